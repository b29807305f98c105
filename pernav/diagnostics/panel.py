"""A panel of drivers and paired episodes for planner and model diagnostics.

The panel mixes named users for whom personal timing pays, a fast keyboard driver, and samples from the
population prior (fixed by seed, drawn before any run), so that no figure is tuned to the named users.
:func:`drive_panel_episode` drives one episode with ``explore``, ``oracle`` or a planner on either the true
simulator (:class:`~pernav.diagnostics.TrueDynamicsEnv`) or a learned model.

Example:
    >>> m = drive_panel_episode(PanelJob("user3, fog, cybertruck", "Town1", 0, 0, "explore", n_traffic=2))
    >>> m["completed"], m["method"]
    (True, 'explore')
"""

from __future__ import annotations

import time
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from pernav.diagnostics.true_model import TrueDynamicsEnv
from pernav.env.torchrl_env import explore_module, navigation_of, oracle_module
from pernav.model.dynamics import DynamicsModel
from pernav.model.navigation import ImaginedNavigationEnv, make_world_model
from pernav.planner.factory import build_planner, env_planning_config
from pernav.study.stats import gap_closed, paired_difference
from pernav.trainer.collect import episode_metrics, history_env
from pernav.world.drivers import Context, population_samples

__all__ = ["PANEL", "PanelJob", "comparison_table", "drive_panel_episode", "episode_key"]

_SAMPLES = population_samples(2)  # population prior samples (seed fixed before any run)

#: label -> (user, context): 2 users the oracle beats explore for by > 20 % (docs/simulator.md), a fast
#: keyboard driver, and 2 population samples.
PANEL: dict[str, tuple[Any, dict[str, str]]] = {
    "user3, fog, cybertruck": ("user3", {"vehicle": "cybertruck", "visual": "foggy"}),
    "user3 (elderly-like)": ("user3", {}),
    "user4, keyboard (fast)": ("user4", {"equipment": "keyboard"}),
    "population sample 0": (_SAMPLES[0][0].to_dict(), _SAMPLES[0][1].to_dict()),
    "population sample 1": (_SAMPLES[1][0].to_dict(), _SAMPLES[1][1].to_dict()),
}


@dataclass(frozen=True)
class PanelJob:
    """One paired episode: a panel driver on a route with a seed, driven by ``method``.

    ``method``: ``explore``, ``oracle``, or ``"<kind>@true"`` / ``"<kind>@learned"`` with ``kind`` a planner
    kind (``retime``, ``paper``); a learned planner needs ``model`` ({"config", "state"}) and may take
    ``params`` (adapted parameters, or a list: an ensemble).
    """

    driver: str
    town: str
    route: int
    seed: int
    method: str
    n_traffic: int = 4
    planner: dict = field(default_factory=dict)  # options over the kind's defaults
    samples: int = 2  # re-seeded copies per imagination on the true simulator
    model: dict | None = None
    params: Any = None


def _policy(job: PanelJob, env: Any) -> Any:
    if job.method in ("explore", "oracle"):
        return explore_module() if job.method == "explore" else oracle_module()
    kind, _, backend = job.method.partition("@")
    options = {"kind": kind, **job.planner}
    if backend == "true":
        return build_planner(TrueDynamicsEnv(navigation_of(env), samples=job.samples, seed=job.seed), options)
    if backend == "learned" and job.model is not None:
        model = DynamicsModel(**job.model["config"])
        model.load_state_dict(job.model["state"])
        planner = build_planner(ImaginedNavigationEnv(make_world_model(model)), options, model.n_actions)
        planner.params = job.params
        return planner
    raise ValueError(f"unknown method {job.method!r}: explore, oracle, <kind>@true or <kind>@learned (with a model)")


def drive_panel_episode(job: PanelJob) -> dict[str, Any]:
    """Drive ``job``; its metrics with the job's labels and the wall time."""
    torch.set_num_threads(1)
    user, context = PANEL[job.driver]
    kind = job.method.partition("@")[0] if "@" in job.method else "paper"
    config = {"n_traffic": job.n_traffic, **env_planning_config({"kind": kind, **job.planner})}
    K = job.model["config"]["K"] if job.model is not None else 5  # the history the learned model reads
    env = history_env(job.town, {"route": job.route, "user": user, "context": Context(**context)}, config=config,
                      seed=job.seed, K=K)
    t0 = time.perf_counter()
    policy = _policy(job, env)
    trajectory = env.rollout(2000, policy=policy, break_when_any_done=True)
    return {"driver": job.driver, "town": job.town, "route": job.route, "seed": job.seed, "method": job.method,
            **episode_metrics(trajectory), "wall_s": round(time.perf_counter() - t0, 1),
            "departures": getattr(policy, "departures", None)}


def episode_key(e: dict[str, Any]) -> tuple:
    """What pairs episodes across methods: the same driver, town, route and seed."""
    return e["driver"], e["town"], e["route"], e["seed"]


def comparison_table(episodes: list[dict[str, Any]]) -> str:
    """Markdown: per method, over the episodes that explore and the oracle also drove, the mean tracking cost,
    explore − method and the gap closed (95 % bootstrap CIs), and collisions, missed turns and extra distance
    beside explore's on the same episodes.

    >>> eps = [{"driver": "d", "town": "Town1", "route": r, "seed": r, "method": m, "tracking_cost": c,
    ...         "collisions": 0, "missed_turns": 0, "extra_distance": 0.0}
    ...        for r in range(3) for m, c in (("explore", 10.0), ("oracle", 6.0), ("x", 8.0))]
    >>> comparison_table(eps).splitlines()[-1].split("|")[1:5]
    [' x ', ' 3 ', ' 8 ', ' +2 [+2, +2] ']
    """
    by: dict[str, dict] = defaultdict(dict)
    for e in episodes:
        by[e["method"]][episode_key(e)] = e
    lines = ["| method | episodes | tracking cost | explore − method (95 % CI) | gap closed (95 % CI) | collisions "
             "(explore) | missed turns (explore) | extra m (explore) |", "|---|---|---|---|---|---|---|---|"]
    for method, eps in by.items():
        keys = [k for k in eps if k in by["explore"] and k in by["oracle"]]
        if not keys:
            continue
        cost = [eps[k]["tracking_cost"] for k in keys]
        ex = [by["explore"][k]["tracking_cost"] for k in keys]
        d = paired_difference(ex, cost)
        g = gap_closed(ex, cost, [by["oracle"][k]["tracking_cost"] for k in keys])

        def total(key: str, src: dict, keys: list = keys) -> float:
            return sum(src[k][key] for k in keys)

        lines.append(f"| {method} | {len(keys)} | {np.mean(cost):.0f} | {d['mean']:+.0f} "
                     f"[{d['low']:+.0f}, {d['high']:+.0f}] "
                     f"| {g['mean']:.0%} [{g['low']:.0%}, {g['high']:.0%}] | {total('collisions', eps):.0f} "
                     f"({total('collisions', by['explore']):.0f}) | {total('missed_turns', eps):.0f} "
                     f"({total('missed_turns', by['explore']):.0f}) | {total('extra_distance', eps):.0f} "
                     f"({total('extra_distance', by['explore']):.0f}) |")
    return "\n".join(lines)
