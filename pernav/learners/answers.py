"""Offline data for the belief about a driver (:mod:`pernav.learners.belief`): simulated drivers of the population prior
drive explore's prompts, and each heard prompt's answer window is labelled with the frame at which the prompt took
effect. That moment is known only because the drivers are simulated (the paper's offline MDPs); the belief never sees
it at round time.

Example:
    >>> drives = labelled_drives("Town1", n=1, population_seed=1, seed=0, config={"n_traffic": 2})
    >>> answers, labels = drives[0].answers, drives[0].labels
    >>> len(answers) == len(labels) > 0 and drives[0].reaction_time > 0
    True
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from pernav.env.navigation import NavigationEnv
from pernav.learners.belief import (
    Answer,
    AnswerDetector,
    DecisionPrior,
    ReactionBelief,
    answers_of,
    frame_series,
    late_probability,
)
from pernav.learners.outcomes import DECISION_GRID, SwerveDetector, TurnOutcome, turn_outcomes
from pernav.trainer.collect import derive_seed
from pernav.world.constants import TURNS
from pernav.world.drivers import DriverProfile, Population, resolve

__all__ = ["EarlyTurn", "LabelledDrive", "drive_outcomes", "fit_belief", "fit_decision", "label",
           "late_probability_each", "labelled_drive", "labelled_drives", "outcome_rows", "record_hearing"]


@dataclass
class LabelledDrive:
    """One explore drive of a simulated driver: its answer windows, each one's true frame (``-1``: no effect inside
    the window: misheard, ignored, or later), and the driver's effective reaction and decision times."""

    answers: list[Answer]
    labels: list[int]
    reaction_time: float
    decision_time: float
    steps: list[dict[str, Any]]  # per step: instruction, played, prompt_end, frames, time, junction, missed (what a
    #                               tracker observes) and swerve (a swerve began in it: the world's record, a label)
    took_effect: dict[float, float | None]  # a played prompt's audio end -> when it took effect (None: misheard/ignored)


def record_hearing(ego: Any) -> list[tuple[float, list[Any]]]:
    """Record every prompt the simulated driver ``ego`` is played, as ``(when, the heard entries it added)`` (none:
    misheard or ignored), without changing the drive (the same draws as unobserved). The simulator's own labels, for
    offline fitting and checks only, never a learner's input at round time."""
    log: list[tuple[float, list[Any]]] = []
    hear = ego.hear

    def recording_hear(instruction: int, playback: str, now: float) -> None:
        before = list(ego.heard)
        hear(instruction, playback, now)
        log.append((now, [h for h in ego.heard if h not in before]))

    ego.hear = recording_hear
    return log


def labelled_drive(town: str, profile: DriverProfile, context: Any, route: int, seed: int,
                   config: Mapping[str, Any] | None = None,
                   policy: Callable[[Mapping[str, Any]], int] | None = None) -> LabelledDrive:
    """Drive explore's prompts for one simulated driver and label each answer window with its true frame; with
    ``policy``, its action from each step's env info instead (e.g. explore re-timed: what an early prompt does)."""
    env = NavigationEnv(town, config=dict(config or {}))
    _, info = env.reset(seed=seed, options={"route": route, "user": profile, "context": context})
    hearing = record_hearing(env.world.ego)
    steps, done, swerves = [], False, 0
    while not done:
        action = int(policy(info)) if policy is not None else int(info["explore_action"])
        _, _, terminated, truncated, info = env.step(action)
        done = terminated or truncated
        steps.append({"instruction": action, "played": bool(info["played"]), "prompt_start": info["prompt_start"],
                      "prompt_end": info["prompt_end"], "frames": info["frames"], "time": info["time"],
                      "junction": info["distance_to_junction"], "missed": info["missed_turns"],
                      "swerve": env.world.events.swerves > swerves})
        swerves = env.world.events.swerves
    series, times = frame_series(torch.from_numpy(np.stack([s["frames"] for s in steps])),
                                 torch.tensor([s["time"] for s in steps]))
    played = [s for s in steps if s["played"]]
    answers = answers_of([s["instruction"] for s in played], [s["prompt_end"] for s in played], series, times,
                         complete=False)
    # prompt start -> when it took effect (None: misheard or ignored)
    active = {round(float(now), 6): (new[0].active_at if new else None) for now, new in hearing}
    took_effect = {s["prompt_end"]: active.get(round(float(s["prompt_start"]), 6)) for s in played}
    driver = resolve(profile, context)
    return LabelledDrive(answers, [label(a, took_effect[a.end]) for a in answers], driver.reaction_time,
                         driver.decision_time, steps, took_effect)


class EarlyTurn:
    """A policy for :func:`labelled_drive`: explore, but each "turn" said as soon as it is ``lead`` steps ahead in
    explore's plan, and left unsaid when explore would say it (an early "turn", then explore's other prompts: what
    ``adapt_driver``'s planner does). Make one per drive.

    >>> policy = EarlyTurn(3)
    >>> policy({"explore_action": 0, "explore_future": [0, 0, 0, 2, 2]})   # 3 steps ahead: said now
    2
    >>> policy({"explore_action": 2, "explore_future": [2]})                # explore says it now: not again
    0
    """

    def __init__(self, lead: int) -> None:
        if lead < 1:
            raise ValueError(f"lead must be at least 1 step; got {lead}")
        self.lead, self.pending = int(lead), None

    def __call__(self, info: Mapping[str, Any]) -> int:
        action, future = int(info["explore_action"]), [int(a) for a in info["explore_future"]]
        if self.pending is not None and action == self.pending:  # explore says it now: it was said already
            self.pending = None
            return 0
        if self.pending is None and action not in TURNS:
            ahead = next((a for a in future[1: self.lead + 1] if a in TURNS), None)
            if ahead is not None:
                self.pending = ahead
                return ahead
        return action


def label(answer: Answer, at: float | None) -> int:
    """The candidate frame of ``answer`` at which its prompt took effect at time ``at`` (the first frame at or after
    it), or ``-1``: it took none (``at`` None) or not inside the window."""
    if at is None:
        return -1
    k = int(torch.searchsorted(answer.frame_times, torch.tensor(at - 1e-6, dtype=answer.frame_times.dtype)))
    return k if k < len(answer.frame_times) and abs(float(answer.frame_times[k]) - at) < 0.15 else -1


def labelled_drives(town: str, n: int, population_seed: int, seed: int,
                    config: Mapping[str, Any] | None = None, progress: bool = False,
                    policy: Callable[[int], Callable[[Mapping[str, Any]], int]] | None = None) -> list[LabelledDrive]:
    """``n`` drivers of ``Population(seed=population_seed)``, one explore drive each on a route drawn from ``seed``
    (with ``policy``, drive ``k``'s policy is ``policy(k)``: :func:`labelled_drive`'s)."""
    population, rng = Population(seed=population_seed), random.Random(seed)
    out = []
    for k in tqdm(range(n), desc=f"{town} belief offline drives", leave=False, disable=not progress):
        profile, context = population.sample()
        out.append(labelled_drive(town, profile, context, rng.randrange(10), derive_seed(seed, town, "belief", k),
                                  config, policy(k) if policy is not None else None))
    return out


def fit_belief(drives: list[LabelledDrive], decision: bool = False,
               **belief_options: float) -> tuple[AnswerDetector, ReactionBelief, SwerveDetector | None]:
    """The detector fitted on the drives' labelled answers, and the prior belief: ``log R`` of the drives' drivers
    (normal), with ``belief_options`` (:class:`ReactionBelief`'s ``noise``, ``outlier``, ``quantile``). With
    ``decision``, the swerve detector fitted on the drives' swerves and the decision time's prior
    (:func:`fit_decision`); else ``None`` and a belief without ``D``."""
    answers = [a for d in drives for a in d.answers]
    labels = [lab for d in drives for lab in d.labels]
    detector = AnswerDetector().fit(answers, labels)
    logs = torch.tensor([math.log(d.reaction_time) for d in drives], dtype=torch.float64)
    swerve, prior = (fit_decision(drives) if decision else (None, None))
    return detector, ReactionBelief(float(logs.mean()), float(logs.std()), decision=prior, **belief_options), swerve


def drive_outcomes(drive: LabelledDrive, swerve: SwerveDetector) -> list[TurnOutcome]:
    """The announced junctions' outcomes in a labelled drive, as a tracker reads them (frames, distances, counts)."""
    frames = torch.from_numpy(np.stack([s["frames"] for s in drive.steps]))
    with torch.no_grad():
        probs = swerve(frames)
    prompts = [(s["instruction"], s["prompt_end"]) for s in drive.steps if s["played"]]
    return turn_outcomes(prompts, torch.tensor([s["time"] for s in drive.steps]),
                         torch.tensor([s["junction"] for s in drive.steps]),
                         torch.tensor([float(s["missed"]) for s in drive.steps]), probs, frames)


def fit_decision(drives: list[LabelledDrive]) -> tuple[SwerveDetector, DecisionPrior]:
    """The swerve detector (on every step's frames, labelled with the world's swerves) and the decision time's prior:
    the drivers' ``D`` (normal), and ``hit`` and ``false`` of :meth:`ReactionBelief.update_turn`'s likelihood by
    maximum likelihood on the drives' turn outcomes under each driver's true ``R`` and ``D``."""
    swerve = SwerveDetector().fit([(torch.from_numpy(np.stack([s["frames"] for s in d.steps])),
                                    torch.tensor([float(s["swerve"]) for s in d.steps])) for d in drives])
    D = torch.tensor([d.decision_time for d in drives], dtype=torch.float64)
    room, late, R = outcome_rows(drives, swerve)
    p_late = late_probability_each(R, room)
    best = None
    for hit in torch.arange(0.05, 1.0, 0.025, dtype=torch.float64):
        for false in (0.001, 0.002, 0.005, 0.01, 0.02, 0.03, 0.05, 0.08, 0.12):
            p = false + (hit - false) * p_late
            ll = float(torch.where(late, p, 1 - p).clamp(min=1e-300).log().sum())
            if best is None or ll > best[0]:
                best = (ll, float(hit), false)
    _, hit, false = best
    return swerve, DecisionPrior(float(D.mean()), float(D.std()), round(hit, 4), false)


def outcome_rows(drives: list[LabelledDrive], swerve: SwerveDetector
                 ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(room, late, R)`` ``[O]`` of every announced junction in ``drives``: the room at its driver's own decision time
    (interpolated on the grid), whether a swerve or a miss followed, and the driver's true mean reaction time."""
    rows = [(o.room, o.late, d.reaction_time, d.decision_time) for d in drives for o in drive_outcomes(d, swerve)]
    if not rows:
        raise ValueError("no announced junction in the offline drives: cannot fit the decision time's likelihood")
    room = torch.cat([torch.from_numpy(np.interp([Dt], DECISION_GRID.numpy(), r.numpy())) for r, _, _, Dt in rows])
    late = torch.tensor([bool(x) for _, x, _, _ in rows])
    return room, late, torch.tensor([r for _, _, r, _ in rows], dtype=torch.float64)


def late_probability_each(R: torch.Tensor, room: torch.Tensor) -> torch.Tensor:
    """``[O]``: :func:`~pernav.learners.belief.late_probability` of each outcome under its own mean reaction ``R``."""
    return torch.stack([late_probability(R[i: i + 1].log(), room[i: i + 1])[0, 0] for i in range(len(room))])
