"""Where independent work runs: in this process, in a pool of processes, or on a Ray cluster.

An episode is described by an :class:`EpisodeJob` (town, user, route, seed and a policy *spec*: a name, or
a model's config + state dict + adapted parameters), so it can be shipped anywhere and gives the same
result everywhere: each worker uses one torch thread and every seed is part of the job.

Example:
    >>> ex = make_executor(workers=1)
    >>> ex.map(abs, [-1, 2, -3])
    [1, 2, 3]
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import threading
import time
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any

__all__ = ["EpisodeJob", "PoolExecutor", "RayExecutor", "SerialExecutor", "init_worker", "make_executor",
           "run_episode_job"]


def _exit_with(parent: int, poll_s: float) -> None:
    while os.getppid() == parent:
        time.sleep(poll_s)
    os._exit(1)  # the parent is gone (killed): nobody will read this worker's results


def _one_thread() -> None:
    import torch

    torch.set_num_threads(1)
    logging.getLogger("torchrl").setLevel(logging.WARNING)


def init_worker(parent: int | None = None, poll_s: float = 1.0) -> None:
    """A pool worker's initializer: one torch thread, quiet torchrl, and exit within ``poll_s`` seconds once
    the parent process ``parent`` is gone (a killed ``pernav study`` would otherwise leave its workers computing).
    The pool passes its own pid: a worker that starts after its parent was killed would read ``os.getppid()``
    as 1 (init) and wait forever."""
    _one_thread()
    parent = os.getppid() if parent is None else parent
    if os.getppid() != parent:  # already orphaned before this initializer ran
        os._exit(1)
    threading.Thread(target=_exit_with, args=(parent, poll_s), daemon=True).start()


def _bar(items: Iterable[Any], desc: str | None, total: int | None = None) -> Iterable[Any]:
    from tqdm.auto import tqdm

    return tqdm(items, desc=desc, total=total, leave=False, disable=desc is None)


class SerialExecutor:
    """Runs everything here, in order."""

    workers = 1

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any], desc: str | None = None) -> list[Any]:
        items = list(items)
        return [fn(x) for x in _bar(items, desc)]

    def close(self) -> None:
        pass


class PoolExecutor:
    """A pool of ``workers`` spawned processes (kept for the executor's life)."""

    def __init__(self, workers: int) -> None:
        self.workers = workers
        self.pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                                        initializer=init_worker, initargs=(os.getpid(),))

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any], desc: str | None = None) -> list[Any]:
        items = list(items)
        return list(_bar(self.pool.map(fn, items), desc, len(items)))

    def close(self) -> None:
        self.pool.shutdown()


class RayExecutor:
    """Ray tasks (one CPU each) on the cluster ``ray.init`` connected to."""

    def __init__(self) -> None:
        import ray

        self.ray = ray
        self.workers = int(ray.cluster_resources().get("CPU", 1))
        self._remote = ray.remote(num_cpus=1)(_call)

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any], desc: str | None = None) -> list[Any]:
        refs = [self._remote.remote(fn, x) for x in items]
        return self.ray.get(refs)

    def close(self) -> None:
        pass


def _call(fn: Callable[[Any], Any], item: Any) -> Any:
    _one_thread()  # a Ray task: Ray owns the worker's life
    return fn(item)


def make_executor(workers: int = 1, ray: bool = False) -> SerialExecutor | PoolExecutor | RayExecutor:
    """Ray tasks, a process pool (``workers > 1``), or this process."""
    if ray:
        return RayExecutor()
    return PoolExecutor(workers) if workers > 1 else SerialExecutor()


@dataclass(frozen=True)
class EpisodeJob:
    """One episode to drive; everything it depends on is in here."""

    cfg: Any  # StudyConfig
    town: str
    entry: Any  # schedule Entry
    route: int
    seed: int
    policy: str  # explore | oracle | mpc | belief
    n_actions: int = 7
    model: dict | None = None  # {"config": ..., "state": state_dict} for mpc
    params: Any = None  # adapted parameters (TensorDict), a belief (dict) for "belief", or None
    policy_name: str = ""  # the study method this episode evaluates


def make_policy(job: EpisodeJob) -> Any:
    """The TensorDictModule that drives ``job``."""
    from pernav.env.torchrl_env import explore_module, info_action_module, oracle_module

    if job.policy == "explore":
        return explore_module()
    if job.policy == "oracle":
        return oracle_module()
    if job.policy == "belief":  # explore's rule re-timed for a belief about the user (the env computes it)
        return info_action_module("belief_action")
    if job.policy != "mpc" or job.model is None:
        raise ValueError(f"unknown policy spec {job.policy!r}")
    from pernav.model.dynamics import DynamicsModel
    from pernav.model.navigation import ImaginedNavigationEnv, make_world_model
    from pernav.planner.factory import build_planner

    model = DynamicsModel(**job.model["config"])
    model.load_state_dict(job.model["state"])
    planner = build_planner(ImaginedNavigationEnv(make_world_model(model)), job.cfg.planner, job.n_actions)
    planner.params = job.params
    return planner


def run_episode_job(job: EpisodeJob) -> dict[str, Any]:
    """Drive the job's episode; its metrics (with the route)."""
    from pernav.study.runner import episode
    from pernav.trainer.collect import episode_metrics

    t0 = time.perf_counter()
    policy = make_policy(job)
    belief = job.params if job.policy == "belief" else None
    trajectory = episode(job.cfg, job.town, job.entry, job.route, job.seed, policy, job.n_actions, belief)
    wall_time = {"episode_s": time.perf_counter() - t0, "planning_s": getattr(policy, "planning_s", 0.0)}
    return {"route": job.route, **episode_metrics(trajectory), "_wall_time": wall_time}
