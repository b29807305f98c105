"""The tracking cost (paper §4.3): one function used by the env, the planner and the metrics.

Works on numpy arrays and torch tensors alike (only ``-``, ``**`` and ``.sum``).

Example:
    >>> import numpy as np
    >>> float(tracking_cost(np.array([3.0, 4.0]), np.array([0.0, 0.0])))
    25.0
"""

from __future__ import annotations

from typing import TypeVar

T = TypeVar("T")


def tracking_cost(position: T, goal: T) -> T:
    """c(s_t) = ||(x_t, y_t) - g_{t-1}||^2 over the last axis (any leading batch shape)."""
    return ((position - goal) ** 2).sum(-1)
