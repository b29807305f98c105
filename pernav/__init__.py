"""pernav: personalized turn-by-turn navigation by online, no-regret, model-based meta RL.

Importing pernav registers the gymnasium ids ``pernav/Town1-v0`` … ``pernav/Town5-v0``.
"""

import gymnasium as gym

from pernav.world.constants import TOWN_NAMES

__version__ = "0.1.0"

for _town in TOWN_NAMES:
    if f"pernav/{_town}-v0" not in gym.registry:
        gym.register(id=f"pernav/{_town}-v0", entry_point="pernav.env.navigation:NavigationEnv",
                     kwargs={"town": _town})
