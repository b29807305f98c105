"""The adaptable world model: dynamics net, L-step loss, one-shot adaptation U(P, tau), TorchRL model env."""

from pernav.model.adapt import adapt, meta_parameters, trajectory_windows
from pernav.model.dynamics import DynamicsModel, apply_delta, ego_delta
from pernav.model.losses import multistep_loss, single_step_loss, using
from pernav.model.world_model import ImaginedNavigationEnv, make_world_model

__all__ = [
    "DynamicsModel",
    "ImaginedNavigationEnv",
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
