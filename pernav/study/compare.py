"""Paired comparison of every method with explore and the oracle over a study's online rounds (95 % CIs).

Every method drives the same episodes in a round (same routes, same seeds), so each episode is a pair.
:func:`compare` pools the pairs of all online rounds — of one study or of several (study seeds) — and
reports, per town and method, the mean of ``explore - method`` with its bootstrap CI, the share of the
explore-to-oracle gap the method closes (all rounds, and only the rounds where that gap exceeds 10 % of
explore's cost: *headroom*), its cost relative to explore in the rounds without headroom, collisions,
missed turns and the extra distance driven beyond the planned route.

Example:
    >>> ep = lambda c: {"tracking_cost": c, "collisions": 0, "missed_turns": 0, "extra_distance": 0.0}
    >>> rnd = {"phase": "online", "towns": {"T": {m: {"episodes": [ep(c), ep(c + 1)]} for m, c in
    ...        (("explore", 10.0), ("adapt", 6.0), ("oracle", 2.0))}}}
    >>> compare([[rnd]])["T"]["adapt"]["gap_closed"]["mean"]
    0.5
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from pernav.study.stats import bootstrap_ci, gap_closed, paired_difference

__all__ = ["HEADROOM", "compare"]

HEADROOM = 0.10  # a round has headroom when the oracle is cheaper than explore by more than this fraction


def _figures(rounds: list[dict[str, Any]], method: str) -> dict[str, Any]:
    def costs(m: str, rs: list[dict[str, Any]]) -> list[float]:
        return [e["tracking_cost"] for r in rs for e in r[m]["episodes"]]

    out: dict[str, Any] = {"rounds": len(rounds)}
    out["explore_minus_method"] = paired_difference(costs("explore", rounds), costs(method, rounds))
    out["tracking_cost"] = bootstrap_ci(costs(method, rounds))[0]
    out["explore_tracking_cost"] = bootstrap_ci(costs("explore", rounds))[0]
    def hits(m: str) -> list[float]:
        return [float(e.get("collisions", 0)) for r in rounds for e in r[m]["episodes"]]

    out["explore_minus_method_collisions"] = paired_difference(hits("explore"), hits(method))  # per episode
    for key in ("collisions", "missed_turns", "extra_distance"):
        out[key] = float(sum(e.get(key, 0) for r in rounds for e in r[method]["episodes"]))
        out[f"explore_{key}"] = float(sum(e.get(key, 0) for r in rounds for e in r["explore"]["episodes"]))
    left = [e["left_explore"] for r in rounds for e in r[method]["episodes"] if e.get("left_explore") is not None]
    if left:  # how often the method's policy departs from explore at all
        out["left_explore"] = float(np.mean(left))
    if all("oracle" in r for r in rounds):
        out["gap_closed"] = gap_closed(costs("explore", rounds), costs(method, rounds), costs("oracle", rounds))
        head = [r for r in rounds if r["oracle"]["tracking_cost"] < (1 - HEADROOM) * r["explore"]["tracking_cost"]]
        flat = [r for r in rounds if r not in head]
        out["headroom_rounds"] = len(head)
        if head:
            out["gap_closed_headroom"] = gap_closed(costs("explore", head), costs(method, head), costs("oracle", head))
        if flat:  # without headroom: the method's cost relative to explore (1.0 = the same)
            ratio = np.mean(costs(method, flat)) / max(np.mean(costs("explore", flat)), 1e-9)
            out["relative_cost_no_headroom"] = float(ratio)
    return out


def _with_round_means(methods: dict[str, Any]) -> dict[str, Any]:
    return {m: {**v, "tracking_cost": float(np.mean([e["tracking_cost"] for e in v["episodes"]]))}
            for m, v in methods.items()}


def compare(studies: Sequence[Sequence[dict[str, Any]]]) -> dict[str, dict[str, Any]]:
    """town -> method -> paired figures against explore, pooled over the online rounds of ``studies`` (each a
    results.json ``iterations`` list; give several for several study seeds)."""
    towns = sorted({t for its in studies for it in its for t in it["towns"]})
    out: dict[str, dict[str, Any]] = {}
    for town in towns:
        rounds = [_with_round_means(it["towns"][town]) for its in studies for it in its
                  if it["phase"] == "online" and town in it["towns"]]
        rounds = [r for r in rounds if "explore" in r]
        methods = sorted({m for r in rounds for m in r if m != "explore"})
        out[town] = {m: _figures([r for r in rounds if m in r], m) for m in methods}
    return out
