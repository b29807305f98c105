"""Tools to look at model error and plans: a true-dynamics world model (``TrueDynamicsEnv``), paired bootstrap
statistics (:mod:`pernav.diagnostics.stats`, defined in :mod:`pernav.study.stats`; light: numpy only), the
planning-error panel, and two diagnostics run as commands: :mod:`pernav.diagnostics.model_check`
(``pernav diagnose model``) and :mod:`pernav.diagnostics.planning_error` (``pernav diagnose planning``)."""

from pernav._lazy import lazy_exports

_NAMES = {"TrueDynamicsEnv": "pernav.diagnostics.true_model",
          **{name: "pernav.study.stats" for name in ("bootstrap_ci", "gap_closed", "paired_difference")}}
__all__ = sorted(_NAMES)
__getattr__, __dir__ = lazy_exports(__name__, _NAMES)
