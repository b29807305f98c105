"""Benchmarks (``pernav bench``): speeds as ratios against a reference measured in the same run.

The machines are shared and noisy, so absolute figures are printed for information and targets are
stated on ratios.

Example:
    >>> figs = run_benchmarks("sim", quick=True)
    >>> figs["sim"]["ratio_vs_intersection"] > 0
    True
"""

from __future__ import annotations

import time
from typing import Any


def _steps_per_second(env, policy, steps: int, seed: int = 0, options: dict | None = None) -> float:
    _, info = env.reset(seed=seed, options=options or {})
    n, t0 = 0, time.perf_counter()
    while n < steps:
        _, _, terminated, truncated, info = env.step(policy(info))
        n += 1
        if terminated or truncated:
            _, info = env.reset(options=options or {})
    return n / (time.perf_counter() - t0)


def bench_sim(quick: bool = False) -> dict[str, Any]:
    """NavigationEnv steps/s (multi-junction town, 8 traffic cars, explore policy) vs highway-env's
    stock ``intersection-v2`` (one junction) stepped with random actions, in the same process."""
    import gymnasium as gym
    import highway_env  # noqa: F401  (registers the stock ids)

    from pernav.env.navigation import NavigationEnv

    steps = 60 if quick else 400
    ours = NavigationEnv("Town3", config={"n_traffic": 8})
    ours_rate = _steps_per_second(ours, lambda info: info["explore_action"], steps, options={"route": 0})
    # The stock env is created after ours: creating it mutates IDMVehicle class constants
    # process-wide (FIELD_NOTES.md); our traffic does not read them.
    stock = gym.make("intersection-v2")
    stock.action_space.seed(0)
    stock_rate = _steps_per_second(stock, lambda info: stock.action_space.sample(), steps // 4)
    stock.close()
    return {
        "pernav_steps_per_s": round(ours_rate, 1),
        "intersection_v2_steps_per_s": round(stock_rate, 1),
        "ratio_vs_intersection": round(ours_rate / stock_rate, 2),
        "pernav_frames_per_step": ours.config["frequency"],
        "intersection_v2_frames_per_step": stock.unwrapped.config["simulation_frequency"]
        // stock.unwrapped.config["policy_frequency"],
        "target": "ratio_vs_intersection >= 1.0",
    }


BENCHMARKS = {"sim": bench_sim}


def run_benchmarks(which: str = "all", quick: bool = False) -> dict[str, dict[str, Any]]:
    """Run one benchmark (``sim``) or ``all``; returns {name: figures}."""
    if which != "all" and which not in BENCHMARKS:
        raise ValueError(f"unknown benchmark {which!r}; choose one of {', '.join(BENCHMARKS)} or all")
    names = list(BENCHMARKS) if which == "all" else [which]
    return {name: BENCHMARKS[name](quick=quick) for name in names}
