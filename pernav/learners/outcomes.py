"""Was a "turn" prompt in time? The evidence about a driver's decision time.

A driver commits to a junction's branch ``decision_time`` seconds before it (:mod:`pernav.world.driver_car`); a
"turn" prompt that takes effect after that moment comes too late: the driver swerves into the turn (harsh braking,
sharp steering) or misses it. Whether that happened is what a navigation can see at each junction it announced:

- a **missed turn**: the navigation's own count (it re-routes at the wrong branch);
- a **swerve**: :class:`SwerveDetector`, a logistic regression on three consecutive steps' summaries of the car's
  frames (braking, deceleration, steering and its jumps), trained offline on simulated drivers whose swerves are
  known (:func:`pernav.learners.answers.fit_belief`). At round time it reads the frames only.

Each announced junction gives one :class:`TurnOutcome`: the slack between its first "turn" prompt's audio end and
the car reaching the junction, and whether a swerve or a miss followed. The likelihood of that outcome under a
driver's reaction and decision times is :meth:`pernav.learners.belief.ReactionBelief.update_turn`'s.

Example:
    >>> frames = torch.zeros(12, 10, 5)
    >>> frames[..., 0] = 10.0                           # 10 m/s, no braking, no steering
    >>> distance = torch.tensor([60., 50., 40., 30., 20., 10., 300., 290., 280., 270., 260., 250.])
    >>> times = torch.arange(1.0, 13.0)
    >>> outcomes = turn_outcomes([(1, 1.5)], times, distance, torch.zeros(12), torch.zeros(12), frames)
    >>> [(round(o.slack, 1), o.late) for o in outcomes]  # the car reached the junction 1 s after step 6 began
    [(5.5, False)]
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from pernav.world.constants import TURNS
from pernav.world.driver_car import DriverCar

__all__ = ["DECISION_GRID", "OUTCOME_AFTER", "STEP_FEATURES", "SwerveDetector", "TurnOutcome", "commit_room",
           "step_summaries", "turn_outcomes"]

OUTCOME_AFTER = 3  # steps after the car reached the junction in which a late turn's swerve or miss shows
PASSED = 5.0  # m: the distance to the next junction grows by more than this when the car passes one
STEP_FEATURES = 8  # per step: max brake, max deceleration, max steering jump, max |steering|, max lane-offset jump,
#                    min and mean speed (/10), share of frames braking hard
APPROACH = 8  # steps before a "turn" prompt whose frames may hold the commit (a prompt after it is late)
DECISION_GRID = torch.linspace(0.6, 5.0, 45, dtype=torch.float64)  # s: the decision times a belief weighs
DECISION_REACH = DriverCar.DECISION_REACH  # m: the latest a driver commits, whatever its decision time
_LOOK = 3  # steps (this and the next two) that the swerve detector reads: a swerve lasts 3 s


def step_summaries(frames: torch.Tensor) -> torch.Tensor:
    """``[T, STEP_FEATURES]``: for each step's frames (``[T, F, C]``, :data:`~pernav.env.navigation.FRAME_KEYS`) the
    summary a swerve shows in: braking and deceleration, steering and its jumps, lane-offset jumps, speed."""
    frames = frames.float()
    speed, acc, brake, steer, offset = frames.unbind(-1)
    before = torch.cat([frames[:1, :1], frames[:-1, -1:]], 0)  # each step's jumps start from the last frame before it
    joined = torch.cat([before, frames], 1)
    jumps = joined.diff(dim=1).abs()
    return torch.stack([brake.amax(1), (-acc).amax(1), jumps[..., 3].amax(1), steer.abs().amax(1),
                        jumps[..., 4].clamp(max=4.0).amax(1), speed.amin(1) / 10.0, speed.mean(1) / 10.0,
                        (brake > 0.7).float().mean(1)], -1)


def _windows(summaries: torch.Tensor) -> torch.Tensor:
    """Each step's summary with the next two steps' (the last step repeated past the drive's end)."""
    padded = torch.cat([summaries, summaries[-1:].expand(_LOOK - 1, -1)])
    return torch.cat([padded[k: k + len(summaries)] for k in range(_LOOK)], -1)


class SwerveDetector(nn.Module):
    """P(a swerve began in this step) from the car's frames of this step and the next two (logistic regression)."""

    def __init__(self) -> None:
        super().__init__()
        self.linear = nn.Linear(STEP_FEATURES * _LOOK, 1)
        self.register_buffer("mean", torch.zeros(STEP_FEATURES * _LOOK))
        self.register_buffer("scale", torch.ones(STEP_FEATURES * _LOOK))

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        """``[T]`` probabilities for a drive's ``[T, F, C]`` frames."""
        x = (_windows(step_summaries(frames)) - self.mean) / self.scale
        return torch.sigmoid(self.linear(x).squeeze(-1))

    def fit(self, drives: list[tuple[torch.Tensor, torch.Tensor]], epochs: int = 500, lr: float = 0.05,
            seed: int = 0) -> SwerveDetector:
        """Fit on drives' ``(frames [T, F, C], swerve began [T] 0/1)``, full-batch Adam, from seeded weights."""
        if not drives:
            raise ValueError("need at least one drive to fit the swerve detector")
        X = torch.cat([_windows(step_summaries(f)) for f, _ in drives])
        y = torch.cat([s.float() for _, s in drives])
        self.mean.copy_(X.mean(0))
        self.scale.copy_(X.std(0).clamp(min=1e-3))
        with torch.random.fork_rng():
            torch.manual_seed(seed)
            self.linear.reset_parameters()
            optimizer = torch.optim.Adam(self.parameters(), lr=lr)
            z = (X - self.mean) / self.scale
            for _ in range(epochs):
                loss = nn.functional.binary_cross_entropy_with_logits(self.linear(z).squeeze(-1), y)
                optimizer.zero_grad()
                loss.backward()
                optimizer.step()
        return self


@dataclass
class TurnOutcome:
    """One announced junction: its first "turn" prompt's audio end, the slack (s) from then to the car reaching the
    junction, whether a swerve or a missed turn followed (the prompt came after the driver's commit), and ``room``:
    for each decision time of :data:`DECISION_GRID`, the time (s) from the audio's end to the moment a driver with
    that decision time committed, read from the car's own speed on its approach (negative: before the prompt)."""

    end: float
    slack: float
    late: bool
    step: int  # the step (index into the drive's steps) in which the car passed the junction
    room: torch.Tensor  # [H]


def commit_room(times: torch.Tensor, speed: torch.Tensor, arrival: float, end: float) -> torch.Tensor:
    """``[H]``: for each decision time ``D`` of :data:`DECISION_GRID`, the time from ``end`` to the first frame (of the
    ``times``/``speed`` series before ``arrival``) at which the junction was within ``max(D v, reach)`` of the car (the
    world's commit rule, :meth:`pernav.world.driver_car.DriverCar._decide_branches`); distances are the car's speed
    integrated back from its arrival."""
    before = times < arrival
    t, v = times[before], speed[before].clamp(min=0.0)
    if len(t) == 0:
        return torch.full((len(DECISION_GRID),), -1.0, dtype=torch.float64)
    step = torch.diff(torch.cat([t, torch.tensor([arrival], dtype=t.dtype)]))
    remaining = torch.flip(torch.cumsum(torch.flip(v * step, [0]), 0), [0])  # [N] m to the junction at each frame
    within = remaining[None] <= torch.maximum(DECISION_GRID[:, None] * v[None], torch.tensor(DECISION_REACH))  # [H, N]
    first = torch.where(within.any(1), within.double().argmax(1), torch.tensor(len(t) - 1))
    return (t.double()[first] - end).to(torch.float64)


def turn_outcomes(prompts: list[tuple[int, float]], times: torch.Tensor, distance: torch.Tensor, missed: torch.Tensor,
                  swerve: torch.Tensor, frames: torch.Tensor, complete: bool = False) -> list[TurnOutcome]:
    """The outcomes of the junctions announced by "turn" prompts (``prompts``: ``(instruction, audio end)`` played,
    in order) in a drive of ``T`` steps: ``times`` each step's end, ``distance`` the distance to the next decision
    junction after it, ``missed`` the navigation's missed-turn count after it, ``swerve`` the swerve detector's
    probabilities, ``frames`` ``[T, F, C]`` (the car's speed on the approach). With ``complete``, only the junctions
    the steps cover to :data:`OUTCOME_AFTER` steps past arrival are returned (a drive in progress)."""
    times, distance, missed = times.float(), distance.float(), missed.float()
    T, F = frames.shape[:2]
    frame_times = ((times.reshape(T, 1) - 1.0) + torch.arange(1, F + 1, dtype=torch.float32) / F).reshape(-1)
    speed = frames[..., 0].float().reshape(-1)
    out, used = [], set()
    for instruction, end in prompts:
        if instruction not in TURNS:
            continue
        after = torch.nonzero(times > end).reshape(-1)
        if len(after) == 0:
            continue
        first = int(after[0])
        passed = [j for j in range(max(first, 1), len(times)) if distance[j] > distance[j - 1] + PASSED]
        if not passed:
            continue
        j = passed[0]
        if j in used:  # a junction counts once, for its first "turn" prompt
            continue
        if complete and j + OUTCOME_AFTER >= len(times):
            continue
        used.add(j)
        arrival = float(times[j - 1]) + float(distance[j - 1]) / float(frames[j - 1, -1, 0].clamp(min=1.0))
        stop = min(j + OUTCOME_AFTER, len(times) - 1)
        late = bool(missed[stop] > missed[max(first - 1, 0)] or (swerve[first: stop + 1] > 0.5).any())
        lo = max(first - 1 - APPROACH, 0) * F  # the approach's frames, from well before the prompt
        room = commit_room(frame_times[lo: j * F], speed[lo: j * F], arrival, float(end))
        out.append(TurnOutcome(float(end), arrival - float(end), late, j, room))
    return out
