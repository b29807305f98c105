"""Environments: the gymnasium NavigationEnv, its TorchRL wrapper and the prompt policies."""

from pernav.env.navigation import DEFAULT_CONFIG, STATE_DIM, STATE_KEYS, NavigationEnv, load_user
from pernav.env.policies import NavView, PromptPolicy, explore_policy, oracle_policy

__all__ = [
    "DEFAULT_CONFIG",
    "STATE_DIM",
    "STATE_KEYS",
    "NavView",
    "NavigationEnv",
    "PromptPolicy",
    "explore_policy",
    "load_user",
    "oracle_policy",
]
