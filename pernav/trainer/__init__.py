"""Training: per-round replay buffers, the Follow-The-Meta-Leader meta-trainer, its ensemble, and collection.

``RoundBuffers``, ``FTMLTrainer``, ``TrainConfig`` and ``EnsembleTrainer`` work with any
:class:`~pernav.model.DynamicsModel`; the collection helpers (``history_env``, ``drive``, ...) drive the
navigation env and load it on first use.
"""

from pernav._lazy import lazy_exports
from pernav.trainer.buffers import KEYS, RoundBuffers
from pernav.trainer.ensemble import EnsembleTrainer
from pernav.trainer.ftml import FTMLTrainer, TrainConfig

_COLLECT = {**{name: "pernav.trainer.collect"
               for name in ("derive_seed", "drive", "episode_metrics", "history_env", "in_action_space",
                            "to_speed_actions")},
            **{name: "pernav.trainer.drives" for name in ("load_drive", "read_metrics", "save_drive")}}
__all__ = ["KEYS", "EnsembleTrainer", "FTMLTrainer", "RoundBuffers", "TrainConfig", *sorted(_COLLECT)]
__getattr__ = lazy_exports(__name__, _COLLECT)[0]


def __dir__() -> list[str]:
    return sorted(__all__)
