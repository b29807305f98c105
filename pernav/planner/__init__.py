"""Discrete tree-search MPC over the learned world model."""

from pernav.planner.tree_search import PlanResult, TreeSearchPlanner

__all__ = ["PlanResult", "TreeSearchPlanner"]
