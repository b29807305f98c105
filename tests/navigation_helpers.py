"""Shared by the test folders: the navigation state's size, a fast Town1 drive and a small seeded DynamicsModel.

Imported as ``navigation_helpers`` from any folder: pytest puts ``tests/`` on ``sys.path`` when it loads
``tests/conftest.py`` (its default ``prepend`` import mode, no ``__init__.py``), as it puts each test's own
folder there for ``study_helpers`` and ``play_helpers``.
"""

from __future__ import annotations

import torch

from pernav.model import DynamicsModel

S = 14  # the navigation state's size
TOWN1 = ("Town1", {"route": 0, "user": "user1"})
FAST = {"n_traffic": 2}


def seeded_model(seed: int, n_actions: int = 7, K: int = 5, hidden: tuple[int, ...] = (16, 16)) -> DynamicsModel:
    """A DynamicsModel initialized after ``torch.manual_seed(seed)`` (the same weights for the same arguments)."""
    torch.manual_seed(seed)
    return DynamicsModel(n_actions=n_actions, K=K, hidden=hidden)

