"""Discrete tree-search MPC: the paper's short-horizon planner and the long-horizon re-timing planner."""

from pernav.planner.factory import PLANNER_DEFAULTS, PLANNER_KINDS, build_planner
from pernav.planner.retiming import RetimedExplore, RetimingPlanner, RetimingResult, candidate_plans
from pernav.planner.tree_search import PlanResult, TreeSearchPlanner

__all__ = ["PLANNER_DEFAULTS", "PLANNER_KINDS", "PlanResult", "RetimedExplore", "RetimingPlanner", "RetimingResult",
           "TreeSearchPlanner", "build_planner", "candidate_plans"]
