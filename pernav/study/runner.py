"""Algorithm 1 per town, with every method, checkpoints and resume (docs/study.md).

Per town: the offline entries are driven by the explore policy into every learner's data stream; the
learners (``sysid``, ``adapt``: 7 actions, ``adapt_speed``: 21) are warm-started by maximum likelihood
(Eq. 1). Then, per online entry ``t``: one trajectory ``tau_t`` of the round's user (by explore, or with
``tau_policy: retimed`` by explore re-timed at random; each offline entry's first drive is its tau, driven the same
way) and ``calibration`` re-timed drives of the user, if configured; adapt ``U(P_t, tau_t)`` (or, with
``train.personal_updates``, that many maximum-likelihood updates from ``P_t`` on the user's drives); evaluate
every method on the evaluation routes with that round's user (same episode seeds for every method);
``rollouts`` trajectories per learner, each by its MPC policy with probability 1/2 and by explore otherwise,
into the learner's own ``D_t``; then FTML meta updates (``adapt``, ``adapt_speed``) or plain updates on all
aggregated data (``sysid``). After the last round, ``hindsight`` is trained with Eq. 3 on all of adapt's
rounds from the same warm start and evaluated per round like ``adapt``.

An entry with recorded drives (a person's, ``pernav play --record``) drives nothing: its drives of the town go
into every learner's round data as simulated drives do (the first is the round's tau). Offline, that is all;
online, the round is a round of data: adapt's losses on it are recorded and the learners update, but no method
is evaluated (nobody can re-drive the person for every method) and no rollouts are collected.

A checkpoint (models, optimizers, buffers, results so far) is written after every entry, atomically (a new folder,
then a manifest with checksums replaced in one ``os.replace``; :mod:`pernav.study.checkpoints`).

Every random choice is derived from (seed, town, entry, purpose), and torch runs on one thread in a town
job, so a town's results do not depend on which process or worker runs it.
"""

from __future__ import annotations

import copy
import json
import logging
import random
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torchrl.record.loggers import CSVLogger
from tqdm.auto import tqdm

from pernav.env.torchrl_env import explore_module
from pernav.learners.answers import fit_belief, labelled_drives
from pernav.learners.belief import BeliefTracker
from pernav.learners.timing import TARGETS as TIMING_TARGETS
from pernav.learners.timing import TimingModel, timing_features
from pernav.model.dynamics import DynamicsModel
from pernav.model.navigation import ImaginedNavigationEnv, make_world_model
from pernav.planner.factory import build_planner
from pernav.planner.retiming import RetimedExplore
from pernav.study.checkpoints import RunState, load_checkpoint, save_checkpoint
from pernav.study.config import LEARNERS, StudyConfig
from pernav.study.driver_rounds import DRIVER_METHODS, SHIFTS, DriverState, fit_driver
from pernav.study.episodes import EpisodeJob, collector, episode, run_episode_job, run_evidence_job
from pernav.study.parallel import SerialExecutor
from pernav.study.schedule import Entry
from pernav.trainer.buffers import RoundBuffers
from pernav.trainer.collect import derive_seed, episode_metrics, in_action_space
from pernav.trainer.drives import load_drive
from pernav.trainer.ensemble import EnsembleTrainer
from pernav.world.constants import N_INSTRUCTIONS
from pernav.world.drivers import Population, resolve

__all__ = ["run_town"]

log = logging.getLogger("pernav.study")


# ----- policies ---------------------------------------------------------------------------------------
class Learner:
    """One learning method: its model, data stream, trainer and MPC planner."""

    def __init__(self, name: str, cfg: StudyConfig, town: str) -> None:
        self.name = name
        self.n_actions = LEARNERS.get(name, N_INSTRUCTIONS)
        self.buffers = RoundBuffers(L=cfg.train.L, seed=derive_seed(cfg.seed, town, name, "buffers"))
        self.trainer = EnsembleTrainer(
            lambda: DynamicsModel(n_actions=self.n_actions, K=cfg.train.K, hidden=cfg.train.hidden,
                                  road=cfg.train.road, context=cfg.train.context), self.buffers,
            cfg.train, size=cfg.train.ensemble, seed=derive_seed(cfg.seed, town, "init", self.n_actions))
        self.model = self.trainer.model
        self.planner = build_planner(ImaginedNavigationEnv(make_world_model(self.model)), cfg.planner, self.n_actions)
        self.meta = name != "sysid"

    def adapted(self, round_: int, cfg: StudyConfig, seed: int = 0) -> Any:
        """The parameters the planner uses in round ``round_``: every member's, adapted to the round's user for
        meta learners (:meth:`~pernav.trainer.EnsembleTrainer.adapted_parameters` on tau and the calibration
        drives); ``None`` (the model's own) for a single sysid model."""
        if not self.meta and cfg.train.ensemble == 1:
            return None
        return self.trainer.adapted_parameters(self.buffers.tau(round_), self.buffers.user_trajectories(round_),
                                               self.meta, seed)

    def add(self, round_: int, trajectory: Any, tau: bool = False, calibration: bool = False) -> None:
        self.buffers.add(round_, in_action_space(trajectory, self.n_actions), tau=tau, calibration=calibration)

    def state(self) -> dict[str, Any]:
        return self.trainer.state_dict()

    def spec(self) -> dict[str, Any]:
        """The model as an :class:`EpisodeJob` ships it (config + a copy of the state dict)."""
        return {"config": self.model.config(), "state": {k: v.clone() for k, v in self.model.state_dict().items()}}


def _tau_policy(cfg: StudyConfig, seed: int) -> Any:
    """The policy of a round's adaptation trajectory tau (``cfg.tau_policy``): explore, or explore re-timed at
    random."""
    return RetimedExplore(seed=derive_seed(seed, "tau")) if cfg.tau_policy == "retimed" else explore_module()


def _policy_spec(method: str, learners: dict[str, Learner], adapted: dict[str, Any]) -> tuple:
    """(policy, n_actions, model, params, policy_name) of an :class:`EpisodeJob` for ``method``."""
    if method in ("explore", "oracle"):
        return method, N_INSTRUCTIONS, None, None, method
    if method in ("timing", "belief", "adapt_driver_formula"):  # explore's rule re-timed for a belief read from tau
        return "belief", N_INSTRUCTIONS, None, adapted[method], method
    if method in DRIVER_METHODS:  # MPC on the hybrid model with the driver's estimate (a tracker)
        return "driver", N_INSTRUCTIONS, None, adapted[method], method
    if method == "best_shift":  # explore's rule shifted by the round's chosen constant
        return "shift", N_INSTRUCTIONS, None, adapted[method], method
    learner = learners[method]
    return "mpc", learner.n_actions, learner.spec(), adapted[method], method


def _summarize(episodes: list[dict[str, Any]]) -> dict[str, Any]:
    n = len(episodes)
    return {
        "tracking_cost": sum(e["tracking_cost"] for e in episodes) / n,
        "collisions": sum(e["collisions"] for e in episodes),
        "vehicle_collisions": sum(e["vehicle_collisions"] for e in episodes),
        "edge_strikes": sum(e["edge_strikes"] for e in episodes),
        "completion": sum(e["completed"] for e in episodes) / n,
        "episodes": episodes,
    }


def _strip_wall_time(metrics: list[dict[str, Any]], profile: dict[str, float], prefix: str) -> list[dict[str, Any]]:
    """Move the episodes' wall-time figures into ``profile`` (they must not enter the results)."""
    for m in metrics:
        t = m.pop("_wall_time", {})
        profile[f"{prefix}_episodes_s"] = profile.get(f"{prefix}_episodes_s", 0.0) + t.get("episode_s", 0.0)
        profile[f"{prefix}_planning_s"] = profile.get(f"{prefix}_planning_s", 0.0) + t.get("planning_s", 0.0)
    return metrics


class _Timer:
    """``with _Timer(profile, "training_s"):`` adds the block's wall time to ``profile``."""

    def __init__(self, profile: dict[str, float], key: str) -> None:
        self.profile, self.key = profile, key

    def __enter__(self) -> None:
        self.t0 = time.perf_counter()

    def __exit__(self, *exc: Any) -> None:
        self.profile[self.key] = self.profile.get(self.key, 0.0) + time.perf_counter() - self.t0


# ----- the town job -----------------------------------------------------------------------------------
@dataclass
class _Town:
    """What every round of one town's run reads and writes."""

    cfg: StudyConfig
    town: str
    learners: dict[str, Learner]
    state: RunState
    executor: Any
    first_online: int

    @property
    def profile(self) -> dict[str, float]:
        return self.state.profile

    def seed(self, *parts: Any) -> int:
        return derive_seed(self.cfg.seed, self.town, *parts)


def run_town(cfg: StudyConfig, town: str, out: str | Path, resume: bool = False, position: int = 0,
             executor: Any = None) -> dict[str, Any]:
    """Run Algorithm 1 for every method in ``town``; returns the town's per-entry results.

    ``executor`` (:mod:`pernav.study.parallel`) runs the evaluation episodes (here, in order, by default).
    """
    torch.set_num_threads(1)
    logging.getLogger("torchrl").setLevel(logging.WARNING)
    out = Path(out)
    ckpt_dir = out / "checkpoints" / town
    entries = cfg.entries_for(town)
    names = [m for m in LEARNERS if m in cfg.methods or (m == "adapt" and "hindsight" in cfg.methods)]
    learners = {name: Learner(name, cfg, town) for name in names}
    state = (load_checkpoint(ckpt_dir, learners) if resume else None) or RunState()
    run = _Town(cfg, town, learners, state, executor or SerialExecutor(),
                next(i for i, e in enumerate(entries) if e.phase == "online"))
    logger = CSVLogger(exp_name=town, log_dir=str(out / "logs"))
    bar = tqdm(total=len(entries), initial=state.next, desc=f"{town} rounds", position=position, leave=False)
    for index in range(state.next, len(entries)):
        entry = entries[index]
        t0 = time.perf_counter()
        rng = random.Random(run.seed(entry.label))
        record: dict[str, Any] = {"label": entry.label, "phase": entry.phase, "methods": {}}
        if entry.drives:  # recorded drives: the round's data, nothing simulated (docs/study.md)
            with _Timer(run.profile, "collection_s"):
                _add_recorded(entry, town, index, learners)
        if entry.phase == "offline":
            _offline_round(run, entry, index, rng, record)
        elif entry.drives:
            _recorded_round(run, entry, index)
        else:
            _online_round(run, entry, index, rng, record)
        state.wall_time[entry.label] = round(time.perf_counter() - t0, 2)
        state.results.append(record)
        _log(logger, index, record)
        state.next = index + 1
        with _Timer(run.profile, "checkpoint_s"):
            save_checkpoint(ckpt_dir, index, state, learners)
        bar.update(1)
    bar.close()
    if "hindsight" in cfg.methods and state.hindsight is None:
        state.hindsight = _hindsight(cfg, town, entries, learners["adapt"], state, list(range(cfg.routes)),
                                     run.executor)
        save_checkpoint(ckpt_dir, len(entries), state, learners)
    _merge_hindsight(state)
    return _town_result(run)


def _offline_round(run: _Town, entry: Entry, index: int, rng: random.Random, record: dict[str, Any]) -> None:
    """An offline entry: explore's drives into every learner's data; after the last one, the warm start (Eq. 1)
    and the timing learner's offline fit."""
    cfg, state = run.cfg, run.state
    if not entry.drives:
        _collect_offline(cfg, run.town, entry, index, rng, run.learners, record, run.profile)
    if index + 1 == run.first_online:
        with _Timer(run.profile, "training_s"):
            _warm_start(cfg, run.learners)
        if "timing" in cfg.methods:
            with _Timer(run.profile, "timing_offline_s"):
                state.timing_model = _fit_timing(cfg, run.town).state_dict()
        driver = any(m in cfg.methods for m in DRIVER_METHODS)
        if "belief" in cfg.methods or driver:
            with _Timer(run.profile, "belief_offline_s"):
                drives = _labelled(cfg, run.town)
                state.belief_model = _fit_belief(cfg, drives)
        if driver:  # the same simulated drivers: the detectors are the belief's; P0 and its offline meta-training
            with _Timer(run.profile, "adapt_driver_offline_s"):
                state.driver = fit_driver(drives, state.belief_model, cfg.belief["noise"], cfg.belief["outlier"])
        state.warm = copy.deepcopy({k: v.state() for k, v in run.learners.items()})  # not live tensors


def _recorded_round(run: _Town, entry: Entry, index: int) -> None:
    """An online entry of a person's recorded drives: a person cannot drive every method's episodes, so it is a
    round of data: adapt's losses on it, then the learners' updates."""
    adapt = run.learners.get("adapt")
    if adapt is not None:
        params = adapt.adapted(index, run.cfg, run.seed(entry.label, "adapt", "personal"))
        _round_losses(run.cfg, run.state, entry, index, adapt, params)
    _train(run)


def _train(run: _Town) -> None:
    with _Timer(run.profile, "training_s"):
        for learner in run.learners.values():
            learner.trainer.train(run.cfg.train.updates, meta=learner.meta)


def _online_round(run: _Town, entry: Entry, index: int, rng: random.Random, record: dict[str, Any]) -> None:
    """An online entry: the user's tau, every method adapted and evaluated on the same episodes, the learners'
    rollouts into their own data, then their updates."""
    cfg, town, learners, state, profile = run.cfg, run.town, run.learners, run.state, run.profile
    tau_route = rng.randrange(10)
    with _Timer(profile, "collection_s"):
        tau_seed = run.seed(entry.label, "tau")
        tau = episode(cfg, town, entry, tau_route, tau_seed, _tau_policy(cfg, tau_seed))
    for learner in learners.values():
        learner.add(index, tau, tau=True)
    _calibrate(cfg, town, entry, index, learners, profile)
    with _Timer(profile, "adaptation_s"):
        adapted = {name: learner.adapted(index, cfg, run.seed(entry.label, name, "personal"))
                   for name, learner in learners.items()}
        if "timing" in cfg.methods:  # the timing learner's belief about this round's user, from tau alone
            adapted["timing"] = TimingModel().load_state_dict(state.timing_model).belief(tau)
            state.timing_beliefs[entry.label] = adapted["timing"]
        if "belief" in cfg.methods:  # the posterior about this round's user: its earlier rounds' taus and this one
            adapted["belief"] = _read_tau(cfg, state, entry, tau)
        driver_methods = [m for m in cfg.methods if m in DRIVER_METHODS]
        if driver_methods:  # U(P, tau) from this user's estimate so far
            adapted.update(DriverState(state.driver).read_tau(_user_key(entry), entry.label, tau, driver_methods))
    if "best_shift" in cfg.methods:
        with _Timer(profile, "best_shift_s"):
            adapted["best_shift"] = _best_shift(run, entry)
    _evaluate(run, entry, adapted, record)
    _rollouts(run, entry, index, rng, adapted)
    if "adapt_driver" in cfg.methods:
        _driver_rollouts(run, entry, adapted["adapt_driver"])
    # the online loss of adapt before the update (for the model-loss regret)
    if "adapt" in learners:
        _round_losses(cfg, state, entry, index, learners["adapt"], adapted["adapt"])
    _train(run)


def _evaluate(run: _Town, entry: Entry, adapted: dict[str, Any], record: dict[str, Any]) -> None:
    """Every method on the round's evaluation routes, on the same episode seeds, into ``record``."""
    methods = [m for m in run.cfg.methods if m != "hindsight"]
    jobs = [EpisodeJob(run.cfg, run.town, entry, route, run.seed(entry.label, "eval", route),
                       *_policy_spec(method, run.learners, adapted))
            for method in methods for route in range(run.cfg.routes)]
    with _Timer(run.profile, "evaluation_s"):
        metrics = run.executor.map(run_episode_job, jobs, desc=f"{run.town} {entry.label} episodes")
    _strip_wall_time(metrics, run.profile, "evaluation")
    for method in methods:
        record["methods"][method] = _summarize([m for j, m in zip(jobs, metrics, strict=True)
                                                if j.policy_name == method])


def _rollouts(run: _Town, entry: Entry, index: int, rng: random.Random, adapted: dict[str, Any]) -> None:
    """Data collection: ``rollouts`` drives per learner, its MPC w.p. 1/2 else explore, into its own D_t."""
    cfg, learners = run.cfg, run.learners
    with _Timer(run.profile, "collection_s"):
        planning_before = sum(learner.planner.planning_s for learner in learners.values())
        for name, learner in learners.items():
            learner.planner.params = adapted[name]
            for k in range(cfg.rollouts):
                use_mpc = rng.random() < 0.5
                route = rng.randrange(10)
                seed = run.seed(entry.label, name, k)
                policy = learner.planner if use_mpc else collector(cfg, seed)
                traj = episode(cfg, run.town, entry, route, seed, policy, learner.n_actions)
                learner.buffers.add(index, traj)  # already in the learner's action space
    run.profile["collection_planning_s"] = run.profile.get("collection_planning_s", 0.0) + sum(
        learner.planner.planning_s for learner in learners.values()) - planning_before


def _driver_rollouts(run: _Town, entry: Entry, tracker: Any) -> None:
    """adapt_driver's data: ``rollouts`` drives of the round's user (its MPC w.p. 1/2, else the collector), whose
    evidence scores ``U(P, tau)`` in the FTML update of its meta model that follows. Its own random stream: the other
    learners' drives are unchanged by it. The drives are independent (each reads a copy of the tracker), so they run
    on the study's executor, in order."""
    cfg, state = run.cfg, DriverState(run.state.driver)
    rng = random.Random(run.seed(entry.label, "adapt_driver", "rollouts"))
    jobs = []
    for k in range(cfg.rollouts):
        use_mpc, route, seed = rng.random() < 0.5, rng.randrange(10), run.seed(entry.label, "adapt_driver", k)
        jobs.append(EpisodeJob(cfg, run.town, entry, route, seed, "driver" if use_mpc else "collector", params=tracker))
    with _Timer(run.profile, "adapt_driver_collection_s"):
        others = run.executor.map(run_evidence_job, jobs, desc=f"{run.town} {entry.label} adapt_driver rollouts")
    with _Timer(run.profile, "adapt_driver_meta_s"):
        state.meta_update(others, entry.label)


def _best_shift(run: _Town, entry: Entry) -> int:
    """The constant shift of explore's rule (:data:`~pernav.study.driver_rounds.SHIFTS`) cheapest for the round's user
    on the true simulator, over the evaluation routes driven with selection seeds (never the evaluation's)."""
    cfg = run.cfg
    jobs = [EpisodeJob(cfg, run.town, entry, route, run.seed(entry.label, "shift selection", route), "shift",
                       params=k, policy_name=str(k)) for k in SHIFTS for route in range(cfg.routes)]
    metrics = run.executor.map(run_episode_job, jobs, desc=f"{run.town} {entry.label} best_shift selection")
    _strip_wall_time(metrics, run.profile, "best_shift")
    costs = {k: sum(m["tracking_cost"] for j, m in zip(jobs, metrics, strict=True) if j.params == k) / cfg.routes
             for k in SHIFTS}
    best = min(SHIFTS, key=lambda k: (costs[k], abs(k)))  # ties: the smaller shift
    run.state.shifts[entry.label] = {"shift": best, "selection_costs": {str(k): round(c, 3) for k, c in costs.items()}}
    return best


def _town_result(run: _Town) -> dict[str, Any]:
    state = run.state
    diagnostics = {name: {"skipped_updates": learner.trainer.skipped, "clipped_updates": learner.trainer.clipped,
                          # U's steps that fell back to the unadapted parameters (no step passed the test on tau)
                          "adapt_fallbacks": learner.trainer.fallbacks,
                          "adapt_fallback_rounds": learner.trainer.fallback_rounds}
                   for name, learner in run.learners.items()}
    if state.timing_beliefs:  # the timing learner ran online
        diagnostics["timing"] = {"beliefs": state.timing_beliefs}
    if state.belief_rounds:
        diagnostics["belief"] = {"beliefs": state.belief_rounds}
    if state.driver is not None:
        diagnostics["adapt_driver"] = {"estimates": state.driver.get("rounds", {}),
                                       "prior0": state.driver["prior0"], "prior": state.driver["prior"]}
    driver_regret = DriverState(state.driver).regret() if state.driver is not None else None
    if state.shifts:
        diagnostics["best_shift"] = state.shifts
    return {"town": run.town, "results": state.results, "online_losses": state.online_losses,
            "unadapted_losses": state.unadapted_losses, "fixed_step_losses": state.fixed_step_losses,
            "diagnostics": diagnostics, "driver_regret": driver_regret,
            "hindsight_losses": (state.hindsight or {}).get("losses", {}), "wall_time": state.wall_time,
            "profile": {k: round(v, 2) for k, v in state.profile.items()}}


def _collect_offline(cfg: StudyConfig, town: str, entry: Entry, index: int, rng: random.Random,
                     learners: dict[str, Learner], record: dict[str, Any], profile: dict[str, float]) -> None:
    """An offline round's simulated drives: ``offline_trajectories`` routes of the entry's driver (the first is
    the round's tau) into every learner's data; explore's episodes are the round's ``explore`` figures."""
    episodes = []
    with _Timer(profile, "collection_s"):
        for k in range(cfg.offline_trajectories):
            route = rng.randrange(10)
            seed = derive_seed(cfg.seed, town, entry.label, "offline", k)
            policy = _tau_policy(cfg, seed) if k == 0 else collector(cfg, seed)  # k = 0 is tau
            traj = episode(cfg, town, entry, route, seed, policy)
            if not isinstance(policy, RetimedExplore):  # the round's explore figures: explore's episodes
                episodes.append({"route": route, **episode_metrics(traj)})
            for learner in learners.values():
                learner.add(index, traj, tau=(k == 0))
    if episodes:  # none when every offline drive is re-timed (collect and tau "retimed")
        record["methods"]["explore"] = _summarize(episodes)


def _add_recorded(entry: Entry, town: str, index: int, learners: dict[str, Learner]) -> None:
    """The entry's recorded drives of ``town`` into every learner's round data exactly as simulated drives go
    there (the same keys and ``traj`` ids; re-encoded for a 21-action learner); the first is the round's tau."""
    for k, path in enumerate(entry.drives_in(town)):
        trajectory = load_drive(path)
        for learner in learners.values():
            learner.add(index, trajectory, tau=(k == 0))


def _round_losses(cfg: StudyConfig, state: RunState, entry: Entry, index: int, learner: Learner,
                  adapted: Any) -> None:
    """adapt's held-out loss on the round's data before the round's update, with the parameters it plans with
    (``adapted``: U on tau, or the personal updates; the model is unchanged), without adaptation and, where U
    backtracks, with the paper's fixed step (the model-loss regret and the adaptation check)."""
    trainer = learner.trainer
    state.online_losses[entry.label] = trainer.round_loss(index, True, adapted)
    state.unadapted_losses[entry.label] = trainer.round_loss(index, adapted=False)
    if not cfg.train.personal_updates and cfg.train.backtrack is not None:  # the paper's fixed step too
        fixed = trainer.parameters(learner.buffers.tau(index), adapted=True, alpha=cfg.train.alpha, fixed_step=True)
        state.fixed_step_losses[entry.label] = trainer.round_loss(index, True, fixed)


def _calibrate(cfg: StudyConfig, town: str, entry: Entry, index: int, learners: dict[str, Learner],
               profile: dict[str, float]) -> None:
    """``cfg.calibration`` drives of the round's user with explore's prompts re-timed at random, before the
    evaluation, into every learner's round data as calibration drives: data that show how *this* user
    answers a prompt's timing, for ``personal_updates`` (an explore tau shows none)."""
    rng = random.Random(derive_seed(cfg.seed, town, entry.label, "calibration"))  # its own stream: the
    with _Timer(profile, "collection_s"):  # round's other draws stay as without calibration
        for k in range(cfg.calibration):
            seed = derive_seed(cfg.seed, town, entry.label, "calibration", k)
            traj = episode(cfg, town, entry, rng.randrange(10), seed, RetimedExplore(seed=seed))
            for learner in learners.values():
                learner.add(index, traj, calibration=True)


def _fit_timing(cfg: StudyConfig, town: str) -> TimingModel:
    """The timing learner's offline phase: ``cfg.timing["offline_drivers"]`` simulated drivers of the population
    prior each drive one explore route of ``town``; their drives' features and their effective reaction and
    decision times (known: they are simulated) fit the :class:`~pernav.learners.timing.TimingModel`."""
    options = cfg.timing
    population = Population(seed=derive_seed(cfg.seed, town, "timing", "population"))
    rng = random.Random(derive_seed(cfg.seed, town, "timing", "routes"))
    features, targets = [], []
    for k in tqdm(range(int(options["offline_drivers"])), desc=f"{town} timing offline drives", leave=False):
        profile, context = population.sample()
        entry = Entry(f"timing offline {k}", "offline", profile.to_dict(), **context.to_dict())
        trajectory = episode(cfg, town, entry, rng.randrange(10), derive_seed(cfg.seed, town, "timing", k),
                             explore_module())
        driver = resolve(profile, context)
        features.append(timing_features(trajectory))
        targets.append(torch.tensor([getattr(driver, name) for name in TIMING_TARGETS]))
    model = TimingModel(l2=options["l2"], quantile=options["quantile"], gate=options["gate"],
                        guard=bool(options["guard"]))
    return model.fit(torch.stack(features), torch.stack(targets))


def _labelled(cfg: StudyConfig, town: str) -> list[Any]:
    """The belief's offline drives: ``cfg.belief["offline_drivers"]`` simulated drivers of the population prior each
    drive one explore route of ``town``, each heard prompt's answer window labelled with the moment it took effect
    (known: they are simulated)."""
    return labelled_drives(town, int(cfg.belief["offline_drivers"]), derive_seed(cfg.seed, town, "belief", "population"),
                           derive_seed(cfg.seed, town, "belief", "routes"), cfg.world_config(), progress=True)


def _fit_belief(cfg: StudyConfig, drives: list[Any]) -> dict[str, Any]:
    """The belief learner's offline phase: the offline drives' labelled answers train the
    :class:`~pernav.learners.belief.AnswerDetector`, and their reaction times give the prior
    (:func:`pernav.learners.answers.fit_belief`)."""
    options = cfg.belief
    detector, prior, swerve = fit_belief(drives, decision=bool(options.get("decision", 0)), noise=options["noise"],
                                         outlier=options["outlier"], quantile=options["quantile"],
                                         drift=options.get("drift", 0.0), slower=options.get("slower", 0.0))
    return {"detector": detector.state_dict(), "prior": prior.state_dict(),
            "swerve": None if swerve is None else swerve.state_dict()}


def _read_tau(cfg: StudyConfig, state: RunState, entry: Entry, tau: Any) -> BeliefTracker:
    """The belief learner's posterior about ``entry``'s user after this round's tau: the prior, or what the earlier
    rounds of the same user left (the belief persists across drives), updated with each of tau's answers."""
    model, user = state.belief_model, _user_key(entry)
    posteriors = state.belief_posteriors
    tracker = BeliefTracker.from_model(model, guard=bool(cfg.belief["guard"]), posterior=posteriors.get(user))
    tracker.observe_drive(tau)
    posteriors[user] = tracker.belief.state_dict()
    low, high = tracker.belief.interval(0.9)
    state.belief_rounds[entry.label] = {
        "reaction_time": round(tracker.belief.mean_reaction(), 4), "interval": [round(low, 4), round(high, 4)],
        "answers": tracker.belief.answers, "acted_on": tracker.fields()}
    if tracker.belief.decision is not None:
        low, high = tracker.belief.decision_interval(0.9)
        state.belief_rounds[entry.label].update({"decision_time": round(tracker.belief.decision_mean, 4),
                                                 "decision_interval": [round(low, 4), round(high, 4)],
                                                 "outcomes": tracker.belief.outcomes})
    return tracker


def _user_key(entry: Entry) -> str:
    """Who drives: the entry's profile and context (a user's rounds share it; the label names the round)."""
    return json.dumps({"profile": entry.profile().to_dict(), "context": entry.context().to_dict()}, sort_keys=True)


def _warm_start(cfg: StudyConfig, learners: dict[str, Learner]) -> None:
    """Eq. 1 on the offline data, then for the meta learners one round's worth of FTML updates on the offline
    rounds (each has its tau), so that U(P, tau) already helps in the first online round. sysid and adapt
    share data, actions and seed: Eq. 1 is trained once and copied."""
    done: dict[int, Learner] = {}
    for learner in learners.values():
        if learner.n_actions in done:
            learner.trainer.load_state_dict(done[learner.n_actions].trainer.state_dict())
            continue
        learner.trainer.fit_normalization()
        learner.trainer.train(cfg.train.warm_updates, meta=False)
        done[learner.n_actions] = learner
    for learner in learners.values():
        if learner.meta:
            learner.trainer.train(cfg.train.updates, meta=True)


def _hindsight(cfg: StudyConfig, town: str, entries: list[Entry], adapt_learner: Learner, state: RunState,
               routes: list[int], executor: Any) -> dict[str, Any]:
    """The best meta model in hindsight: Eq. 3 over all of adapt's rounds from the same warm start."""
    hind = Learner("adapt", cfg, town)
    hind.trainer.load_state_dict(state.warm["adapt"])
    hind.buffers = adapt_learner.buffers
    hind.trainer.buffers = adapt_learner.buffers
    online = [(i, e) for i, e in enumerate(entries) if e.phase == "online"]
    with _Timer(state.profile, "hindsight_training_s"):
        hind.trainer.train(cfg.train.updates * len(online), meta=True)
    out: dict[str, Any] = {"evaluations": {}, "losses": {}}
    params = {index: hind.adapted(index, cfg, derive_seed(cfg.seed, town, entry.label, "hindsight", "personal"))
              for index, entry in online}
    jobs = [EpisodeJob(cfg, town, entry, route, derive_seed(cfg.seed, town, entry.label, "eval", route),
                       "mpc", N_INSTRUCTIONS, hind.spec(), params[index], policy_name="hindsight")
            for index, entry in online if not entry.drives for route in routes]  # recorded rounds: no episodes
    with _Timer(state.profile, "hindsight_evaluation_s"):
        metrics = executor.map(run_episode_job, jobs, desc=f"{town} hindsight episodes")
    _strip_wall_time(metrics, state.profile, "hindsight")
    for index, entry in online:
        if not entry.drives:
            out["evaluations"][entry.label] = _summarize([m for j, m in zip(jobs, metrics, strict=True)
                                                          if j.entry.label == entry.label])
        out["losses"][entry.label] = hind.trainer.round_loss(index, True, params[index] if cfg.train.personal_updates
                                                             else None)
    return out


def _merge_hindsight(state: RunState) -> None:
    evaluations = (state.hindsight or {}).get("evaluations", {})
    for record in state.results:
        if record["label"] in evaluations:
            record["methods"]["hindsight"] = evaluations[record["label"]]


def _log(logger: Any, step: int, record: dict[str, Any]) -> None:
    for method, figures in record["methods"].items():
        logger.log_scalar(f"{method}/tracking_cost", figures["tracking_cost"], step=step)
        logger.log_scalar(f"{method}/collisions", figures["collisions"], step=step)
