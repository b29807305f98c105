"""Drive episodes with a prompt policy: per-episode metrics, optional GIF replay.

Example:
    >>> out = drive_routes("Town1", "explore", "user1", routes=[0], n_traffic=2)
    >>> out["episodes"][0]["completed"]
    True
"""

from __future__ import annotations

from typing import Any

import imageio.v2 as imageio
import numpy as np

from pernav.env.navigation import NavigationEnv, load_user
from pernav.world.towns import TownError

METRICS = ("tracking_cost", "vehicle_collisions", "edge_strikes", "collisions", "missed_turns",
           "wrong_turns", "reroutes", "extra_distance", "completed", "time")


def run_episode(env: NavigationEnv, policy: str, route: int, seed: int, frames: list | None = None,
                options: dict | None = None) -> dict[str, Any]:
    """One episode of ``policy`` ('explore' or 'oracle') on ``route``; returns its metrics."""
    _, info = env.reset(seed=seed, options={"route": route, **(options or {})})
    key = {"explore": "explore_action", "oracle": "oracle_action"}[policy]
    if frames is not None:
        frames.append(env.render())
    done = False
    while not done:
        _, _, terminated, truncated, info = env.step(info[key])
        done = terminated or truncated
        if frames is not None:
            frames.append(env.render())
    return {"route": route, **{k: info[k] for k in METRICS}}


def drive_routes(town: str, policy: str, user: Any, routes: list[int] | None = None, context: dict | None = None,
                 seed: int = 0, n_traffic: int = 8, gif: str | None = None) -> dict[str, Any]:
    """Drive ``routes`` of ``town`` with ``policy`` and ``user`` (name, mapping or file); the
    seed of route ``r`` is ``seed + r`` so one route's outcome does not depend on the others."""
    if policy not in ("explore", "oracle"):
        raise ValueError(f"unknown policy {policy!r}; choose explore or oracle")
    env = NavigationEnv(town, config={"n_traffic": n_traffic}, render_mode="rgb_array" if gif else None)
    routes = list(range(len(env.town.routes))) if routes is None else routes
    for r in routes:
        if not 0 <= r < len(env.town.routes):
            raise TownError(f"route index {r} out of range [0, {len(env.town.routes) - 1}] for {town}")
    profile, ctx = load_user(user)
    options = {"user": profile, "context": {**(ctx.to_dict() if ctx else {}), **(context or {})}}
    episodes = []
    for i, r in enumerate(routes):
        frames: list | None = [] if gif and i == 0 else None
        episodes.append(run_episode(env, policy, r, seed + r, frames, options))
        if frames:
            imageio.mimsave(gif, frames, duration=0.1, loop=0)
    env.close()
    summary = {
        "tracking_cost": float(np.mean([e["tracking_cost"] for e in episodes])),
        "collisions": int(sum(e["collisions"] for e in episodes)),
        "vehicle_collisions": int(sum(e["vehicle_collisions"] for e in episodes)),
        "edge_strikes": int(sum(e["edge_strikes"] for e in episodes)),
        "completion": float(np.mean([e["completed"] for e in episodes])),
    }
    return {"town": town, "policy": policy, "user": profile.to_dict(), "context": options["context"],
            "seed": seed, "episodes": episodes, "summary": summary}
