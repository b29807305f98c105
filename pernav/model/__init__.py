"""The adaptable world model: dynamics net (any state), L-step loss, one-shot adaptation U(P, tau), TorchRL model envs."""

from pernav.model.adapt import adapt, meta_parameters, trajectory_windows
from pernav.model.dynamics import DELTAS, DynamicsModel, EgocentricDifferences, PlainDifferences, apply_delta, ego_delta
from pernav.model.imagined import ImaginedEnv, PlainWorldModel
from pernav.model.losses import multistep_loss, single_step_loss, using
from pernav.model.world_model import ImaginedNavigationEnv, make_world_model

__all__ = [
    "DELTAS",
    "DynamicsModel",
    "EgocentricDifferences",
    "ImaginedEnv",
    "ImaginedNavigationEnv",
    "PlainDifferences",
    "PlainWorldModel",
    "adapt",
    "apply_delta",
    "ego_delta",
    "make_world_model",
    "meta_parameters",
    "multistep_loss",
    "single_step_loss",
    "trajectory_windows",
    "using",
]
