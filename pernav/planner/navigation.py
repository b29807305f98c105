"""The navigation's planners, in one place: the paper's :class:`TreeSearchPlanner` (a configuration of the generic
:class:`~pernav.planner.DiscreteTreeSearchPlanner`), the default :class:`RetimingPlanner` and :func:`build_planner`,
which builds either from a study's options. Each lives in its own module (``tree_search``, ``retiming``,
``factory``); they read the navigation env's planning context and its tracking cost.
"""

from pernav.planner.factory import PLANNER_DEFAULTS, PLANNER_KINDS, build_planner, env_planning_config, parse_planner_options
from pernav.planner.retiming import Departure, RetimedExplore, RetimingPlanner, RetimingResult, candidate_plans
from pernav.planner.tree_search import TreeSearchPlanner

__all__ = ["PLANNER_DEFAULTS", "PLANNER_KINDS", "Departure", "RetimedExplore", "RetimingPlanner", "RetimingResult",
           "TreeSearchPlanner", "build_planner", "candidate_plans", "env_planning_config", "parse_planner_options"]
