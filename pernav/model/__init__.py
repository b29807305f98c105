"""The adaptable world model: dynamics net (any state), L-step loss, one-shot adaptation U(P, tau), TorchRL model envs.

The navigation's own parts live in :mod:`pernav.model.navigation` (``ImaginedNavigationEnv``, ``make_world_model``)
and :mod:`pernav.model.egocentric` (``EgocentricDifferences``, ``apply_delta``, ``ego_delta``); they also import from
here, on first use.
"""

from pernav._lazy import lazy_exports
from pernav.model.adapt import MAX_NORM, AdaptInfo, LossFn, adapt, meta_parameters, trajectory_windows
from pernav.model.dynamics import DELTAS, DynamicsModel, PlainDifferences
from pernav.model.imagined import ImaginedEnv, PlainWorldModel, model_device
from pernav.model.losses import multistep_loss, single_step_loss, using

__all__ = [
    "DELTAS",
    "MAX_NORM",
    "AdaptInfo",
    "DynamicsModel",
    "ImaginedEnv",
    "LossFn",
    "PlainDifferences",
    "PlainWorldModel",
    "adapt",
    "meta_parameters",
    "model_device",
    "multistep_loss",
    "single_step_loss",
    "trajectory_windows",
    "using",
]

_NAVIGATION = {**{name: "pernav.model.navigation" for name in ("ImaginedNavigationEnv", "make_world_model")},
               **{name: "pernav.model.egocentric" for name in ("EgocentricDifferences", "apply_delta", "ego_delta")}}
__getattr__ = lazy_exports(__name__, _NAVIGATION)[0]


def __dir__() -> list[str]:
    return sorted([*__all__, *_NAVIGATION])
