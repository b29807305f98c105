"""Environments: the gymnasium NavigationEnv, its TorchRL wrapper and the prompt policies.

The names below load on first use (the env needs highway-env; ``pernav.env.layout`` does not).
"""

from pernav._lazy import lazy_exports

_EXPORTS = {
    "DEFAULT_CONFIG": "pernav.env.navigation",
    "STATE_DIM": "pernav.env.layout",
    "STATE_KEYS": "pernav.env.layout",
    "NavigationEnv": "pernav.env.navigation",
    "load_user": "pernav.env.navigation",
    "NavView": "pernav.env.policies",
    "PromptPolicy": "pernav.env.policies",
    "explore_policy": "pernav.env.policies",
    "oracle_policy": "pernav.env.policies",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
