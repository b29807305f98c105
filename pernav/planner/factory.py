"""One place that builds a planner from a study's ``planner`` options (``kind: retime | paper``).

Example:
    >>> from pernav.model import DynamicsModel
    >>> from pernav.model.navigation import ImaginedNavigationEnv, make_world_model
    >>> env = ImaginedNavigationEnv(make_world_model(DynamicsModel(hidden=(8,))))
    >>> type(build_planner(env, {"kind": "paper", "horizon": 5})).__name__
    'TreeSearchPlanner'
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields
from typing import Any

from pernav.planner.retiming import Departure, RetimingPlanner
from pernav.planner.tree_search import TreeSearchPlanner
from pernav.world.constants import N_ADAPTIVE_ACTIONS
from pernav.world.files import key_values

__all__ = ["PLANNER_KINDS", "PLANNER_DEFAULTS", "build_planner", "env_planning_config", "parse_planner_options"]

#: The options each planner kind takes, with their defaults (``kind`` selects one). ``delay`` is 0: a
#: delayed prompt is the departure a learned model mispredicts worst (a held "prepare to turn" made the
#: 12-driver study's catastrophe), and over 3 seeds of the default study adapt without delays was better in
#: both towns, paired (docs/research/findings.md, "Without delays: the default since 2026-11-24").
PLANNER_DEFAULTS: dict[str, dict[str, Any]] = {
    "retime": {"horizon": 12, "advance": 6, "delay": 0, "route_weight": 1.0, "progress_weight": 1.0,
               "margin": 20.0, "rel_margin": 0.05, "agree": 1.0, "max_spread": 2.0, "rel_spread": 0.0, "wait": False},
    "paper": {"horizon": 5, "shift": 2, "bonus": 20.0, "beam_speed": 64},
}
PLANNER_KINDS = tuple(PLANNER_DEFAULTS)


def build_planner(env: Any, options: Mapping[str, Any], n_actions: int | None = None) -> Any:
    """The planner ``options["kind"]`` (default ``retime``) on ``env``; unknown options raise ``ValueError``.

    ``n_actions`` (7 or 21) picks the paper planner's beam for the 21-action space (``beam_speed``).
    """
    options = dict(options)
    kind = options.pop("kind", "retime")
    if kind not in PLANNER_DEFAULTS:
        raise ValueError(f"unknown planner kind {kind!r}; choose one of {', '.join(PLANNER_KINDS)}")
    unknown = sorted(set(options) - set(PLANNER_DEFAULTS[kind]))
    if unknown:
        raise ValueError(f"unknown {kind} planner option {unknown[0]!r}; allowed: "
                         f"kind, {', '.join(PLANNER_DEFAULTS[kind])}")
    opts = {**PLANNER_DEFAULTS[kind], **options}
    if kind == "paper":
        beam = opts.pop("beam_speed")
        return TreeSearchPlanner(env, beam=beam if n_actions == N_ADAPTIVE_ACTIONS else None, **opts)
    departure = Departure(**{f.name: opts.pop(f.name) for f in fields(Departure) if f.name in opts})
    return RetimingPlanner(env, departure=departure, **opts)


def env_planning_config(options: Mapping[str, Any]) -> dict[str, int]:
    """The navigation env's config entries the planner ``options`` need (lengths of the planning context).

    >>> env_planning_config({"kind": "retime", "horizon": 10, "advance": 4})
    {'plan_horizon': 5, 'plan_shift': 2, 'future_steps': 14}
    """
    kind = options.get("kind", "retime")
    opts = {**PLANNER_DEFAULTS.get(kind, {}), **options}
    if kind == "paper":
        return {"plan_horizon": int(opts["horizon"]), "plan_shift": int(opts["shift"])}
    return {"plan_horizon": 5, "plan_shift": 2, "future_steps": int(opts["horizon"]) + int(opts["advance"])}


def parse_planner_options(kind: str, pairs: list[str]) -> dict[str, Any]:
    """``KEY=VALUE`` strings (JSON values: numbers, true/false, null) as options of the planner ``kind``;
    ``ValueError`` naming the bad pair and what is allowed.

    >>> parse_planner_options("retime", ["max_spread=null", "agree=0.67"])
    {'max_spread': None, 'agree': 0.67}
    """
    if kind not in PLANNER_DEFAULTS:
        raise ValueError(f"unknown planner kind {kind!r}; choose one of {', '.join(PLANNER_KINDS)}")
    out: dict[str, Any] = {}
    for key, value, pair in key_values(pairs, PLANNER_DEFAULTS[kind], f"the {kind} planner's options"):
        # not JSON, a JSON string or a list: refused like any value that is no number
        if value is not None and not isinstance(value, (int, float)):
            raise ValueError(f"{pair!r}: VALUE must be a number, true/false or null")
        out[key] = value
    return out
