"""Study configuration and presets (``smoke``, ``default``, ``paper``, ``personal``, ``personal_paper``).

Example:
    >>> cfg = preset("smoke")
    >>> cfg.towns, len(cfg.entries_for("Town1")) >= 3
    (['Town1'], True)
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from pernav.study.headroom import personal_schedule, sweep_schedule
from pernav.study.schedule import Entry, check_recorded, paper_schedule
from pernav.trainer.ftml import TrainConfig
from pernav.world.towns import TOWN_NAMES

__all__ = ["COLLECT", "METHODS", "PRESETS", "TIMING_DEFAULTS", "PresetError", "StudyConfig", "preset"]

METHODS = ("explore", "sysid", "adapt", "adapt_speed", "hindsight", "timing", "oracle")
COLLECT = ("explore", "retimed")  # StudyConfig.collect and StudyConfig.tau choices
LEARNERS = {"sysid": 7, "adapt": 7, "adapt_speed": 21}  # learning methods and their action counts
# the timing learner (pernav.model.timing): simulated population drivers it learns from offline per town, the
# ridge penalty, the residual SDs its belief adds to the predicted mean, and the gate (s earlier than explore)
TIMING_DEFAULTS: dict[str, Any] = {"offline_drivers": 48, "l2": 3.0, "quantile": 1.5, "gate": 0.0}


class PresetError(ValueError):
    """Unknown preset or invalid study option."""


@dataclass
class StudyConfig:
    """Everything that determines a study's results (saved in results.json as ``config``)."""

    preset: str
    towns: list[str]
    schedule: list[Entry]
    routes: int = 10  # evaluation routes per round (the town's first ``routes``)
    rollouts: int = 4  # K trajectories per online round and learner (MPC w.p. 1/2, else explore)
    offline_trajectories: int = 4  # explore trajectories per offline round
    n_traffic: int = 8
    # the paper's methods and the oracle; the timing learner joins in the presets that run it
    methods: list[str] = field(default_factory=lambda: [m for m in METHODS if m != "timing"])
    train: TrainConfig = field(default_factory=TrainConfig)
    planner: dict[str, Any] = field(default_factory=lambda: {"kind": "retime"})  # see pernav.planner.factory
    # the learners' non-MPC data: "explore" (the paper) or "retimed" (explore with its prompts re-timed at
    # random, pernav.planner.RetimedExplore, so the data identify what a prompt's timing does). The tau
    # trajectories (unless tau is "retimed") and every evaluation stay pure explore either way.
    collect: str = "explore"
    # the policy that drives each round's adaptation trajectory tau (paper: "one trajectory with the exploration
    # policy"): "explore" (the rule itself) or "retimed" (RetimedExplore, so tau shows this driver's answer to a
    # prompt's timing, which one explore drive cannot). Every evaluation episode stays pure explore either way
    tau: str = "explore"
    # re-timed drives (RetimedExplore) of each online round's user before its evaluation, beside tau: data of
    # this user's answers to a prompt's timing (train.personal_updates adapts on them; 0: none, the paper)
    calibration: int = 0
    timing: dict[str, Any] = field(default_factory=lambda: dict(TIMING_DEFAULTS))  # the timing learner's options
    seed: int = 0

    def entries_for(self, town: str) -> list[Entry]:
        return [e for e in self.schedule if e.runs_in(town)]

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["schedule"] = [e.to_dict() for e in self.schedule]
        out["train"] = self.train.to_dict()
        return out

    def validate(self) -> None:
        bad = [t for t in self.towns if t not in TOWN_NAMES]
        if bad:
            raise PresetError(f"unknown town {bad[0]!r}; choose from {', '.join(TOWN_NAMES)}")
        if not self.towns:
            raise PresetError("no towns to run")
        unknown = [m for m in self.methods if m not in METHODS]
        if unknown:
            raise PresetError(f"unknown method {unknown[0]!r}; choose from {', '.join(METHODS)}")
        if self.collect not in COLLECT:
            raise PresetError(f"collect must be one of {', '.join(COLLECT)}, got {self.collect!r}")
        if self.tau not in COLLECT:
            raise PresetError(f"tau must be one of {', '.join(COLLECT)}, got {self.tau!r}")
        if not 1 <= self.routes <= 10:
            raise PresetError(f"routes must be in [1, 10], got {self.routes}")
        if self.rollouts < 0 or self.offline_trajectories < 1:
            raise PresetError("rollouts must be >= 0 and offline_trajectories >= 1")
        if self.calibration < 0 or self.train.personal_updates < 0:
            raise PresetError(f"calibration and train.personal_updates must be >= 0, got {self.calibration} and "
                              f"{self.train.personal_updates}")
        if not 0.0 <= self.train.personal_replay < 1.0:
            raise PresetError(f"train.personal_replay must be in [0, 1), got {self.train.personal_replay}")
        if self.train.personal_replay and not self.train.personal_updates:
            raise PresetError("train.personal_replay needs train.personal_updates > 0 (it mixes the personal "
                              "updates' data); got personal_updates 0")
        if self.train.backtrack is not None and not 0.0 < self.train.backtrack < 1.0:
            raise PresetError(f"train.backtrack must be in (0, 1) or null (the paper's fixed step), got "
                              f"{self.train.backtrack}")
        if self.train.road and self.planner.get("kind") == "paper" and "adapt_speed" in self.methods:
            raise PresetError(f"train.road = {self.train.road} with the paper planner: adapt_speed's beam search "
                              "needs a model without the road; drop adapt_speed from the methods or use road 0")
        for town in self.towns:
            phases = [e.phase for e in self.entries_for(town)]
            if "offline" not in phases or "online" not in phases:
                raise PresetError(f"town {town}: the schedule gives it no offline or no online entry")
        unknown = sorted(set(self.timing) - set(TIMING_DEFAULTS))
        if unknown:
            raise PresetError(f"unknown timing option {unknown[0]!r}; allowed: {', '.join(TIMING_DEFAULTS)}")
        if int(self.timing["offline_drivers"]) < 2 or self.timing["l2"] < 0 or self.timing["gate"] < 0:
            raise PresetError(f"timing needs offline_drivers >= 2, l2 >= 0 and gate >= 0; got {self.timing}")
        check_recorded(self.schedule, self.towns, self.train.K)  # recorded drives: their towns and K


def _select(labels: list[str]) -> list[Entry]:
    by_label = {e.label: e for e in paper_schedule()}
    return [by_label[x] for x in labels]


def _smoke() -> StudyConfig:
    return StudyConfig(
        preset="smoke", towns=["Town1"], schedule=_select(["Offline 0", "Online 0", "Online 8"]),
        routes=1, rollouts=1, offline_trajectories=2, n_traffic=2,
        train=TrainConfig(updates=3, batch=32, warm_updates=20, hidden=[32, 32], rounds_per_update=2, ensemble=2,
                          personal_updates=5),
        planner={"kind": "retime"}, collect="retimed", calibration=1, methods=list(METHODS),
        timing={**TIMING_DEFAULTS, "offline_drivers": 4})


def _default() -> StudyConfig:
    # Two towns (Town3 has a roundabout); six online rounds: a vehicle change (cybertruck), fog, and three
    # other users; ~10 minutes on a 2-core laptop with 2 workers.
    labels = ["Offline 0", "Offline 1", "Offline 2", "Online 0", "Online 2", "Online 5", "Online 8",
              "Online 9", "Online 11"]
    return StudyConfig(
        preset="default", towns=["Town1", "Town3"], schedule=_select(labels),
        routes=3, rollouts=2, offline_trajectories=3, n_traffic=4,
        # three smaller models rather than one large: the planner leaves explore only where all three agree;
        # a 10-step history spans a prompt, the driver's reaction and the turn (memory is 8-30 s)
        train=TrainConfig(updates=50, batch=128, warm_updates=300, rounds_per_update=2, hidden=[128, 128], K=10,
                          ensemble=3),
        # calibration drives + personal updates (--calibration 4 --personal-updates 100) are not the default:
        # over 3 seeds they closed 22 % [-12 %, 66 %] of Town3's gap but added 2 collisions and 45 % run time
        # (docs/findings.md, "End to end with calibration drives and personal updates"; world v1)
        collect="retimed")


def _personal(paper_sized: bool = False) -> StudyConfig:
    # the headroom benchmark (pernav.study.headroom, docs/personal.md): sixteen online rounds across the spectrum
    # of drivers, ten of them outside explore's slack; the default preset's learning options
    cfg = _default()
    cfg.preset = "personal_paper" if paper_sized else "personal"
    cfg.schedule = personal_schedule()
    cfg.routes = 10 if paper_sized else 4
    cfg.towns = list(TOWN_NAMES) if paper_sized else ["Town1", "Town3"]
    cfg.methods = ["explore", "sysid", "adapt", "timing", "oracle"]
    return cfg


def _paper() -> StudyConfig:
    return StudyConfig(preset="paper", towns=list(TOWN_NAMES), schedule=paper_schedule(), routes=10, rollouts=4,
                       offline_trajectories=4, n_traffic=8)


def _personal_sweep() -> StudyConfig:
    # the headroom sweep: the average driver with its reaction time shifted (pernav.study.headroom.SWEEP_SHIFTS)
    cfg = _personal()
    cfg.preset, cfg.schedule = "personal_sweep", sweep_schedule()
    cfg.methods = ["explore", "adapt", "timing", "oracle"]
    return cfg


PRESETS = {"smoke": _smoke, "default": _default, "paper": _paper, "personal": _personal,
           "personal_paper": lambda: _personal(paper_sized=True), "personal_sweep": _personal_sweep}


def preset(name: str) -> StudyConfig:
    """A fresh copy of a preset's configuration."""
    if name not in PRESETS:
        raise PresetError(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}")
    return PRESETS[name]()
