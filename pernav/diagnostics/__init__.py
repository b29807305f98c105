"""Tools to look at model error and plans: a true-dynamics world model (``TrueDynamicsEnv``)."""

from pernav.diagnostics.true_model import TrueDynamicsEnv

__all__ = ["TrueDynamicsEnv"]
