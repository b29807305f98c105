"""Discrete tree-search MPC for any discrete-action model env (:class:`DiscreteTreeSearchPlanner`).

The navigation's planners (the paper's ``TreeSearchPlanner``, the default ``RetimingPlanner``, ``build_planner``)
live in their own modules (``tree_search``, ``retiming``, ``factory``), gathered in :mod:`pernav.planner.navigation`;
they also import from here, on first use, so importing this package loads none of the navigation (its cost, its
layout).
"""

from pernav._lazy import lazy_exports
from pernav.planner.discrete import DiscreteTreeSearchPlanner, SearchResult

__all__ = ["DiscreteTreeSearchPlanner", "SearchResult"]

_NAVIGATION = {**{name: "pernav.planner.factory" for name in ("PLANNER_DEFAULTS", "PLANNER_KINDS", "build_planner")},
               **{name: "pernav.planner.retiming"
                  for name in ("Departure", "RetimedExplore", "RetimingPlanner", "RetimingResult", "candidate_plans")},
               "TreeSearchPlanner": "pernav.planner.tree_search"}
__getattr__ = lazy_exports(__name__, _NAVIGATION)[0]


def __dir__() -> list[str]:
    return sorted([*__all__, *_NAVIGATION])
