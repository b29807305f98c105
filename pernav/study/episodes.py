"""One episode of a study: the env of a (town, round, route) cell and an :class:`EpisodeJob`, everything an episode
depends on (town, user, route, seed and a policy *spec*: a name, or a model's config + state dict + adapted
parameters), so that any executor (:mod:`pernav.study.parallel`) can drive it anywhere with the same result.

Example:
    >>> from pernav.study.config import preset
    >>> cfg = preset("smoke")
    >>> job = EpisodeJob(cfg, "Town1", cfg.schedule[0], route=0, seed=1, policy="explore")
    >>> make_policy(job).out_keys
    ['action']
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

from pernav.env.torchrl_env import explore_module, info_action_module, oracle_module
from pernav.learners.driver import DriverPlanner
from pernav.model.dynamics import DynamicsModel
from pernav.model.navigation import ImaginedNavigationEnv, make_world_model
from pernav.planner.factory import build_planner, env_planning_config
from pernav.planner.retiming import RetimedExplore, ShiftedExplore
from pernav.study.config import StudyConfig
from pernav.study.driver_rounds import DRIVER_PLANNER
from pernav.study.schedule import Entry
from pernav.trainer.collect import derive_seed, drive, episode_metrics, history_env
from pernav.world.constants import N_ADAPTIVE_ACTIONS, N_INSTRUCTIONS

__all__ = ["EpisodeJob", "collector", "episode", "make_policy", "run_episode_job", "run_evidence_job", "study_env"]


def collector(cfg: StudyConfig, seed: int) -> Any:
    """The learners' non-MPC data-collection policy (``cfg.collect``): explore, or explore re-timed at random."""
    if cfg.collect == "retimed":
        return RetimedExplore(seed=derive_seed(seed, "retimed"))
    return explore_module()


def study_env(cfg: StudyConfig, town: str, entry: Entry, route: int, seed: int, n_actions: int = N_INSTRUCTIONS,
              belief: dict[str, float] | None = None, explore_table: bool = False) -> Any:
    """The history-windowed TorchRL env of a study's cell: ``entry``'s user on ``route`` of ``town``, the study's
    traffic and planning context, and the env's ``belief`` about the user where a method reads one (and explore's
    table where a planner imagines explore closed loop)."""
    config = {**cfg.world_config(), "adaptive_speed": n_actions == N_ADAPTIVE_ACTIONS,
              **env_planning_config(cfg.planner), "explore_table": explore_table}
    if belief is not None:
        config["belief"] = belief
    options = {"route": route, "user": entry.profile(), "context": entry.context()}
    return history_env(town, options, config=config, seed=seed, K=cfg.train.K)


def episode(cfg: StudyConfig, town: str, entry: Entry, route: int, seed: int, policy: Any, n_actions: int = N_INSTRUCTIONS,
            belief: dict[str, float] | None = None) -> Any:
    """Drive ``policy`` through the cell's episode; the trajectory (a TensorDict)."""
    return drive(study_env(cfg, town, entry, route, seed, n_actions, belief), policy)


@dataclass(frozen=True)
class EpisodeJob:
    """One episode to drive; everything it depends on is in here."""

    cfg: StudyConfig
    town: str
    entry: Entry
    route: int
    seed: int
    policy: str  # explore | oracle | mpc | belief | driver | shift | collector
    n_actions: int = N_INSTRUCTIONS
    model: dict | None = None  # {"config": ..., "state": state_dict} for mpc
    params: Any = None  # adapted parameters (TensorDict), a belief for "belief", a tracker for "driver" (and for
    # run_evidence_job's "collector"), a shift, or None
    policy_name: str = ""  # the study method this episode evaluates


def make_policy(job: EpisodeJob) -> Any:
    """The TensorDictModule that drives ``job``."""
    if job.policy == "explore":
        return explore_module()
    if job.policy == "oracle":
        return oracle_module()
    if job.policy == "belief":  # explore's rule re-timed for a belief about the user (the env computes it)
        return info_action_module("belief_action")
    if job.policy == "driver":  # adapt_driver: MPC on the hybrid model, its tracker following the drive
        return DriverPlanner(job.params.copy(), DRIVER_PLANNER)
    if job.policy == "collector":
        return collector(job.cfg, job.seed)
    if job.policy == "shift":
        return ShiftedExplore(int(job.params), plan_shift=int(env_planning_config(job.cfg.planner).get("plan_shift", 2)))
    if job.policy != "mpc" or job.model is None:
        raise ValueError(f"unknown policy spec {job.policy!r}")
    model = DynamicsModel(**job.model["config"])
    model.load_state_dict(job.model["state"])
    planner = build_planner(ImaginedNavigationEnv(make_world_model(model)), job.cfg.planner, job.n_actions)
    planner.params = job.params
    return planner


def run_episode_job(job: EpisodeJob) -> dict[str, Any]:
    """Drive the job's episode; its metrics (with the route)."""
    t0 = time.perf_counter()
    policy = make_policy(job)
    belief = job.params if job.policy == "belief" else None
    trajectory = episode(job.cfg, job.town, job.entry, job.route, job.seed, policy, job.n_actions, belief)
    wall_time = {"episode_s": time.perf_counter() - t0, "planning_s": getattr(policy, "planning_s", 0.0)}
    return {"route": job.route, **episode_metrics(trajectory), "_wall_time": wall_time}


def run_evidence_job(job: EpisodeJob) -> Any:
    """Drive the job's episode and read it with a copy of its tracker (``job.params``): the drive's evidence about the
    driver (:class:`~pernav.learners.driver.Evidence`), what adapt_driver's rollouts give its FTML update."""
    trajectory = episode(job.cfg, job.town, job.entry, job.route, job.seed, make_policy(job), job.n_actions)
    reader = job.params.copy()
    reader.observe_drive(trajectory)
    return reader.belief.evidence
