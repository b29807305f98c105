"""Discrete tree-search MPC: a generic planner for any discrete-action model env, the paper's short-horizon
navigation planner (a configuration of it) and the long-horizon re-timing planner."""

from pernav.planner.discrete import DiscreteTreeSearchPlanner, SearchResult
from pernav.planner.factory import PLANNER_DEFAULTS, PLANNER_KINDS, build_planner
from pernav.planner.retiming import RetimedExplore, RetimingPlanner, RetimingResult, candidate_plans
from pernav.planner.tree_search import TreeSearchPlanner

__all__ = ["PLANNER_DEFAULTS", "PLANNER_KINDS", "DiscreteTreeSearchPlanner", "RetimedExplore", "RetimingPlanner",
           "RetimingResult", "SearchResult", "TreeSearchPlanner", "build_planner", "candidate_plans"]
