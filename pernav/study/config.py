"""Study configuration and its presets, one YAML file each in ``pernav/study/presets/`` (``smoke``, ``default``,
``paper``, ``personal``, ``personal_paper``, ``personal_sweep``, ``split``, ``repeat``).

Example:
    >>> cfg = preset("smoke")
    >>> cfg.towns, len(cfg.entries_for("Town1")) >= 3
    (['Town1'], True)
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import yaml

from pernav.study.benchmarks import SCHEDULES as BENCHMARK_SCHEDULES
from pernav.study.schedule import Entry, check_recorded, paper_schedule
from pernav.trainer.ftml import TrainConfig
from pernav.world.constants import N_ADAPTIVE_ACTIONS, N_INSTRUCTIONS, TOWN_NAMES
from pernav.world.files import key_values

__all__ = ["BELIEF_DEFAULTS", "COLLECT", "DEFAULT_METHODS", "METHODS", "PRESETS", "RENAMED_OPTIONS", "TIMING_DEFAULTS",
           "PresetError", "StudyConfig", "current_names", "learner_options", "preset"]

METHODS = ("explore", "sysid", "adapt", "adapt_speed", "hindsight", "timing", "belief", "adapt_driver",
           "adapt_driver_static", "adapt_driver_prior", "adapt_driver_formula", "best_shift", "oracle")
# what a preset runs unless it names its methods: adapt_driver's ablations and best_shift (the reference, which drives
# every shift of explore's rule on selection episodes each round) run where a preset or --methods asks for them
DEFAULT_METHODS = tuple(m for m in METHODS if m not in ("adapt_driver_static", "adapt_driver_prior",
                                                        "adapt_driver_formula", "best_shift"))
COLLECT = ("explore", "retimed")  # StudyConfig.collect and StudyConfig.tau_policy choices
# learning methods and their action counts
LEARNERS = {"sysid": N_INSTRUCTIONS, "adapt": N_INSTRUCTIONS, "adapt_speed": N_ADAPTIVE_ACTIONS}
# the timing learner (pernav.learners.timing): simulated population drivers it learns from offline per town, the
# ridge penalty, the residual SDs its belief adds to the predicted mean, the gate (s earlier than explore), and the
# guard (1: never a prompt so early that the quickest driver the evidence allows acts on it a junction too soon, nor
# before the car is inside the last junction box before the one meant)
TIMING_DEFAULTS: dict[str, Any] = {"offline_drivers": 48, "l2": 3.0, "quantile": 1.5, "gate": 0.0, "guard": 1}
# the belief learner (pernav.learners.belief): simulated population drivers whose prompts' answers train its detector per
# town, the detector's timing noise (log s) and outlier share in the likelihood, the posterior SDs above the mean that
# the prompts are timed for, the guard (as the timing learner's), decision (1: a posterior over the decision time
# too, from the announced junctions' swerves and missed turns; 0: the reaction time only) and drift (SD of a driver's
# own reading error, log s: the posterior about the reaction time never narrows below it) and slower (the posterior
# probability that the driver is slower than the average driver that re-timing for the reaction time needs). decision
# 0, drift 0 and slower 0 is the learner as judged first; slower 0 the second version (docs/personal.md)
BELIEF_DEFAULTS: dict[str, Any] = {"offline_drivers": 96, "noise": 0.15, "outlier": 0.3, "quantile": 1.0, "guard": 1,
                                   "decision": 1, "drift": 0.1, "slower": 0.5}
# options renamed since configurations were saved (presets, study.json, results.json's config): old name -> new.
# ``tau`` named the policy of the adaptation drive; tau is the drive itself
RENAMED_OPTIONS = {"tau": "tau_policy"}


class PresetError(ValueError):
    """Unknown preset or invalid study option."""


def learner_options(pairs: list[str], options: dict[str, Any], learner: str, integers: tuple[str, ...]) -> None:
    """``--LEARNER-option KEY=VALUE`` pairs into ``options`` (numbers only; ``integers`` kept whole); a bad pair
    raises :class:`PresetError` naming the flag.

    >>> options = dict(BELIEF_DEFAULTS)
    >>> learner_options(["quantile=1.5"], options, "belief", ("offline_drivers",))
    >>> options["quantile"]
    1.5
    """
    try:
        parsed = key_values(pairs, list(options), f"the {learner} options")
    except ValueError as exc:
        raise PresetError(f"--{learner}-option {exc}") from None
    for key, value, pair in parsed:
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise PresetError(f"--{learner}-option {pair!r}: VALUE must be a number")
        options[key] = int(value) if key in integers else float(value)


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
    # every method: the paper's, the timing learner (it joined after its sized judging, docs/personal.md) and the oracle
    methods: list[str] = field(default_factory=lambda: list(DEFAULT_METHODS))
    train: TrainConfig = field(default_factory=TrainConfig)
    planner: dict[str, Any] = field(default_factory=lambda: {"kind": "retime"})  # see pernav.planner.factory
    # the learners' non-MPC data: "explore" (the paper) or "retimed" (explore with its prompts re-timed at
    # random, pernav.planner.RetimedExplore, so the data identify what a prompt's timing does). The tau
    # trajectories (unless tau_policy is "retimed") and every evaluation stay pure explore either way.
    collect: str = "explore"
    # the policy that drives each round's adaptation trajectory tau (paper: "one trajectory with the exploration
    # policy"): "explore" (the rule itself) or "retimed" (RetimedExplore, so tau shows this driver's answer to a
    # prompt's timing, which one explore drive cannot). Every evaluation episode stays pure explore either way
    tau_policy: str = "explore"
    # re-timed drives (RetimedExplore) of each online round's user before its evaluation, beside tau: data of
    # this user's answers to a prompt's timing (train.personal_updates adapts on them; 0: none, the paper)
    calibration: int = 0
    # every episode the study drives is cut after this factor x the route's nominal time + 30 s (None: the env's own
    # limit, pernav.env.navigation's time_limit_factor, 2.0). For quick checks of the machinery (the test suite's
    # studies cut it to 0.15): a cut episode is not a whole drive, so its figures are not the study's
    time_limit_factor: float | None = None
    timing: dict[str, Any] = field(default_factory=lambda: dict(TIMING_DEFAULTS))  # the timing learner's options
    belief: dict[str, Any] = field(default_factory=lambda: dict(BELIEF_DEFAULTS))  # the belief learner's options
    seed: int = 0

    def entries_for(self, town: str) -> list[Entry]:
        return [e for e in self.schedule if e.runs_in(town)]

    def world_config(self) -> dict[str, Any]:
        """The navigation env's options that the study sets for every episode it drives (traffic, time limit).

        >>> StudyConfig("smoke", ["Town1"], [], n_traffic=2, time_limit_factor=0.3).world_config()
        {'n_traffic': 2, 'time_limit_factor': 0.3}
        """
        limit = {} if self.time_limit_factor is None else {"time_limit_factor": self.time_limit_factor}
        return {"n_traffic": self.n_traffic, **limit}

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
        if self.tau_policy not in COLLECT:
            raise PresetError(f"tau_policy must be one of {', '.join(COLLECT)}, got {self.tau_policy!r}")
        if not 1 <= self.routes <= 10:
            raise PresetError(f"routes must be in [1, 10], got {self.routes}")
        if self.rollouts < 0 or self.offline_trajectories < 1:
            raise PresetError("rollouts must be >= 0 and offline_trajectories >= 1")
        if self.time_limit_factor is not None and not self.time_limit_factor > 0:
            raise PresetError(f"time_limit_factor must be > 0 or null (the env's own limit), got "
                              f"{self.time_limit_factor}")
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
        unknown = sorted(set(self.belief) - set(BELIEF_DEFAULTS))
        if unknown:
            raise PresetError(f"unknown belief option {unknown[0]!r}; allowed: {', '.join(BELIEF_DEFAULTS)}")
        b = self.belief
        if int(b["offline_drivers"]) < 2 or b["noise"] < 0 or not 0 <= b["outlier"] < 1 or b["quantile"] < 0:
            raise PresetError(f"belief needs offline_drivers >= 2, noise >= 0, outlier in [0, 1) and quantile >= 0; "
                              f"got {self.belief}")
        check_recorded(self.schedule, self.towns, self.train.K)  # recorded drives: their towns and K


PRESETS_DIR = Path(__file__).parent / "presets"
#: the named presets: ``pernav/study/presets/NAME.yaml``
PRESETS = tuple(sorted(p.stem for p in PRESETS_DIR.glob("*.yaml")))
#: the schedules a preset may name; ``{"paper": [labels]}`` picks the paper's entries by label
SCHEDULES = {"paper": paper_schedule, **BENCHMARK_SCHEDULES}


def _schedule(spec: Any, name: str) -> list[Entry]:
    if isinstance(spec, dict) and list(spec) == ["paper"]:
        by_label = {e.label: e for e in paper_schedule()}
        missing = [x for x in spec["paper"] if x not in by_label]
        if missing:
            raise PresetError(f"preset {name}: no paper entry labelled {missing[0]!r}")
        return [by_label[x] for x in spec["paper"]]
    if spec not in SCHEDULES:
        raise PresetError(f"preset {name}: schedule must be one of {', '.join(SCHEDULES)} or {{paper: [labels]}}")
    return SCHEDULES[spec]()


def current_names(saved: dict[str, Any]) -> dict[str, Any]:
    """A saved configuration's top-level options under today's names (:data:`RENAMED_OPTIONS`), in their order.

    >>> current_names({"collect": "explore", "tau": "retimed"})
    {'collect': 'explore', 'tau_policy': 'retimed'}
    """
    return {RENAMED_OPTIONS.get(key, key): value for key, value in saved.items()}


def _preset_fields(name: str) -> dict[str, Any]:
    """The preset's fields, its ``base`` preset's first (a preset's ``train``, ``timing`` and ``belief`` add to the
    base's)."""
    fields = current_names(yaml.safe_load((PRESETS_DIR / f"{name}.yaml").read_text()) or {})
    base = fields.pop("base", None)
    if base is None:
        return fields
    merged = _preset_fields(base)
    for key, value in fields.items():
        merged[key] = {**merged.get(key, {}), **value} if key in ("train", "timing", "belief") else value
    return merged


def preset(name: str) -> StudyConfig:
    """A fresh copy of a preset's configuration (``pernav/study/presets/NAME.yaml``)."""
    if name not in PRESETS:
        raise PresetError(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}")
    fields = _preset_fields(name)
    fields["schedule"] = _schedule(fields.get("schedule"), name)
    fields["train"] = TrainConfig(**fields.get("train", {}))
    fields["timing"] = {**TIMING_DEFAULTS, **fields.get("timing", {})}
    fields["belief"] = {**BELIEF_DEFAULTS, **fields.get("belief", {})}
    return StudyConfig(preset=name, **fields)
