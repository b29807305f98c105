"""``adapt_driver``: the paper's Algorithm 1 on a world model that can represent a driver.

The world model (:mod:`pernav.model.driver`) is hybrid: what the navigation knows (its route, its prompts and their
audio, the car's speed) is not learned; its driver part has per-driver parameters ``phi = (log R, D)``, the mean
reaction time and the decision time, which are what adaptation changes. Its observation part reads, from the frames the
navigation senses between decisions, when each prompt took effect and whether an announced junction was swerved at or
missed (the belief's detectors, fitted offline on simulated drivers: :mod:`pernav.learners.answers`). Everything else
is the meta model ``P`` (:class:`DriverPrior`): the centre and spread ``phi`` starts from, one prompt's reaction spread
``sigma``, the detectors' error rates.

* ``U(P, tau)`` (:func:`adapt_phi`): one step on ``tau``'s loss (the negative log-likelihood of its answers and
  outcomes under ``phi``, plus ``P``'s proximal term), preconditioned by its curvature (a Newton step), halved until
  ``tau``'s loss is no worse than at the start, so ``U`` never makes ``tau``'s own loss worse.
* Follow-The-Meta-Leader (:func:`meta_train`): after each round, ``P``'s centre and spread minimize, over every round
  so far, the loss of the *other* drives of that round's driver under ``U(P, tau)`` (:func:`meta_loss`), and never
  end worse on it than they started; offline, over simulated population drivers (each drive's first half adapts,
  its second half scores).
* The driver's estimate updates within a drive (``U`` from the estimate before the drive, on the drive so far, after
  every answer: :class:`DriverTracker`) and across drives (the estimate after a drive is the next one's start).
* MPC: :class:`~pernav.planner.retiming.RetimingPlanner` searches re-timings of explore's plan on the hybrid model with
  this driver's parameters (:class:`DriverPlanner`), at the predictive quantiles of one prompt's reaction time.

Example:
    >>> import torch
    >>> prior = DriverPrior.population(log_r=(0.2, 0.4), decision=(2.0, 0.5))
    >>> slow = Evidence(answers=[(torch.tensor([3.0, 3.1, 3.2]), torch.tensor([0.1, 0.8, 0.1]), 0.0)] * 4)
    >>> quick = Evidence(answers=[(torch.tensor([0.7, 0.8, 0.9]), torch.tensor([0.1, 0.8, 0.1]), 0.0)] * 4)
    >>> adapt_phi(prior, slow).reaction_time > prior.reaction_time > adapt_phi(prior, quick).reaction_time
    True
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from pernav.env.navigation import FRAME_KEYS
from pernav.env.policies import explore_policy
from pernav.learners.belief import DT, AnswerDetector, BeliefTracker, frame_series
from pernav.learners.outcomes import DECISION_GRID, SwerveDetector
from pernav.model.driver import DriverImaginedEnv, DriverParams
from pernav.planner.retiming import Departure, RetimingPlanner
from pernav.world.constants import AUDIO_DURATION, PREPARES, TURNS

__all__ = ["DriverBelief", "DriverPlanner", "DriverPrior", "DriverTracker", "Evidence", "Response", "adapt_phi",
           "meta_loss", "meta_train", "prepare_shares", "read_prepared", "read_response", "tau_loss"]

MIN_SD = 0.05  # the smallest spread of P or of an estimate (log s; s): never certain
CRUISE_QUANTILE = 0.9  # the share of a drive's frames slower than the cruise read from it
NEAR_JUNCTION = 8.0  # m: a "turn" step this close to its junction drives at the driver's turn speed
APPROACH = 80.0  # m: a "turn" step's braking this close to its junction is braking for the turn
MOVING = 0.5  # m/s, m/s^2: slower frames (stopped at a line, in a queue) and weaker pedals say nothing of the driver
NEWTON_HALVINGS = 8  # U halves its step at most this often before it keeps the start
PREPARE_WINDOW = 6.0  # s after a "prepare" took effect over which its slowing is read
MOVING_AT = 3.0  # m/s: a "prepare" heard slower than this (queued, stopped) says nothing of its slowing


@dataclass
class Evidence:
    """What the navigation read of a driver in drives: each answer's candidate delays (s after the audio's end), the
    detector's probability of each and of no visible answer; each announced junction's ``room`` (``[H]`` over
    :data:`~pernav.learners.outcomes.DECISION_GRID`: s from the "turn" prompt's audio end to that decision time's
    commit) and whether a swerve or a miss followed."""

    answers: list[tuple[torch.Tensor, torch.Tensor, float]] = field(default_factory=list)
    outcomes: list[tuple[torch.Tensor, bool]] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.answers) + len(self.outcomes)

    def packed(self) -> dict[str, Any]:
        """The evidence as padded tensors (computed once): answers' ``delays`` ``[A, K]`` (clamped at 0.05 s; padding
        1 s at probability 0), ``probs``, the log of each window's end ``last``, ``none``; outcomes' ``room``
        ``[O, H]`` and ``late``."""
        key = (len(self.answers), len(self.outcomes))
        cached = getattr(self, "_packed", None)
        if cached is not None and cached[0] == key:
            return cached[1]
        out: dict[str, Any] = {"delays": None, "room": None}
        if self.answers:
            K = max(len(d) for d, _, _ in self.answers)
            delays = torch.ones(len(self.answers), K, dtype=torch.float64)
            probs = torch.zeros(len(self.answers), K, dtype=torch.float64)
            for i, (d, p, _) in enumerate(self.answers):
                delays[i, : len(d)], probs[i, : len(p)] = d.double().clamp(min=0.05), p.double()
            out.update(delays=delays, probs=probs,
                       last=torch.tensor([math.log(float(d.double().clamp(min=0.05)[-1]) + DT / 2)
                                          for d, _, _ in self.answers], dtype=torch.float64),
                       none=torch.tensor([n for _, _, n in self.answers], dtype=torch.float64))
        if self.outcomes:
            out.update(room=torch.stack([r.double() for r, _ in self.outcomes]),
                       late=torch.tensor([bool(x) for _, x in self.outcomes]))
        self._packed = (key, out)
        return out

    def __add__(self, other: Evidence) -> Evidence:
        return Evidence(self.answers + other.answers, self.outcomes + other.outcomes)

    def halves(self) -> tuple[Evidence, Evidence]:
        """The first and the second half (in the order read): one adapts, the other scores."""
        a, o = len(self.answers) // 2, len(self.outcomes) // 2
        return Evidence(self.answers[:a], self.outcomes[:o]), Evidence(self.answers[a:], self.outcomes[o:])

    def state(self) -> dict[str, Any]:
        return {"answers": [(d.clone(), p.clone(), float(n)) for d, p, n in self.answers],
                "outcomes": [(r.clone(), bool(late)) for r, late in self.outcomes]}

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> Evidence:
        return cls([tuple(a) for a in state["answers"]], [tuple(o) for o in state["outcomes"]])


@dataclass(frozen=True)
class Response:
    """What a driver's drives say of its speeds (m/s, m/s^2), read from the frames the navigation senses
    (:func:`read_response`): the speed it cruises at, drives a turn at, its braking for a turn and its acceleration.

    >>> Response().turn_speed
    5.0
    """

    cruise: float = 10.0
    turn_speed: float = 5.0
    brake: float = 2.0
    accel: float = 1.5
    prepared: float = 0.75  # the share of its cruise it drives at after a "prepare" (:func:`read_prepared`)

    def to_dict(self) -> dict[str, float]:
        return {k: round(float(v), 3) for k, v in self.__dict__.items()}


def read_response(trajectory: TensorDictBase, default: Response = Response(), reaction: float | None = None
                  ) -> Response:
    """The driver's speeds in ``trajectory`` (a drive: ``"action"``, ``"distance_to_junction"`` and the
    ``("next", "frames")`` the car's sensors gave): its cruise (a high quantile of its speeds), its turn speed (the
    median speed of the "turn" steps within :data:`NEAR_JUNCTION` of their junction), its braking for a turn (the
    median deceleration of the "turn" steps within :data:`APPROACH`) and its acceleration (the median of its
    accelerating frames); ``default``'s where the drive shows none (no turn, never braked). Given the driver's mean
    ``reaction`` time as known before the drive, also the share of its cruise it drives at after a "prepare"
    (:func:`read_prepared`; else ``default``'s).

    >>> from tensordict import TensorDict
    >>> frames = torch.zeros(3, 10, 5); frames[..., 0] = torch.tensor([12.0, 9.0, 4.0])[:, None]
    >>> frames[1, :, 1] = -2.5
    >>> tau = TensorDict({"action": torch.tensor([0, 1, 1]), "distance_to_junction": torch.tensor([90.0, 40.0, 5.0]),
    ...                   "next": {"frames": frames}}, [3])
    >>> r = read_response(tau); (r.cruise, r.turn_speed, r.brake, r.accel)
    (12.0, 4.0, 2.5, 1.5)
    """
    speed, acc = FRAME_KEYS.index("speed"), FRAME_KEYS.index("acceleration")
    frames = trajectory["next", "frames"].double()
    if not frames.numel():
        return default
    action = trajectory["action"].reshape(-1).long()
    dj = trajectory["distance_to_junction"].reshape(-1).double()
    turn = torch.isin(action, torch.tensor([int(t) for t in TURNS]))

    def median(x: torch.Tensor, fallback: float) -> float:
        return float(x.median()) if x.numel() else fallback

    near = frames[turn & (dj <= NEAR_JUNCTION)][..., speed].reshape(-1)
    braking = -frames[turn & (dj <= APPROACH)][..., acc].reshape(-1)
    rising = frames[..., acc].reshape(-1)
    cruise = float(frames[..., speed].reshape(-1).quantile(CRUISE_QUANTILE))
    return Response(cruise=cruise,
                    turn_speed=median(near[near > MOVING], default.turn_speed),
                    brake=median(braking[braking > MOVING], default.brake),
                    accel=median(rising[rising > MOVING], default.accel),
                    prepared=default.prepared if reaction is None else read_prepared(trajectory, reaction, cruise,
                                                                                     default.prepared))


def prepare_shares(speed: torch.Tensor, times: torch.Tensor, effects: list[float], ends: list[float], cruise: float
                   ) -> list[float]:
    """For each "prepare" that took effect at ``effects[i]`` (s) and whose "turn" was said at ``ends[i]``, the median
    of the car's ``speed`` (frames at ``times``) from its effect until then (at most :data:`PREPARE_WINDOW` s), over
    the driver's ``cruise``, at most 1. The median of the window, not its least speed: the braking for the junction
    that begins within it is the approach's, not the prompt's (a driver that does not slow on a "prepare" reads 1).
    A "prepare" heard at under :data:`MOVING_AT` m/s or with under three frames to read says nothing.

    >>> t = torch.arange(1, 101) / 10.0; v = torch.where(t < 3.0, 10.0, 8.0)
    >>> prepare_shares(v, t, [2.0, 9.5], [8.0, 9.6], cruise=10.0)  # the second: two frames, too few
    [0.8]
    """
    shares = []
    for effect, end in zip(effects, ends, strict=True):
        window = (times >= effect) & (times <= min(end, effect + PREPARE_WINDOW))
        start = speed[int(torch.argmin((times - effect).abs()))]
        if int(window.sum()) >= 3 and float(start) > MOVING_AT:
            shares.append(round(min(float(speed[window].median()) / max(cruise, MOVING), 1.0), 6))
    return shares


def read_prepared(trajectory: TensorDictBase, reaction: float, cruise: float, default: float) -> float:
    """The share of its ``cruise`` a driver drives at after a "prepare" in ``trajectory`` (a drive: ``"action"`` and
    the ``("next", "frames")``), each "prepare" said (not held) taken to act its audio plus ``reaction`` s later (the
    driver's mean reaction time as known before the drive) until its "turn" is said (:func:`prepare_shares`); their
    mean, shrunk toward ``default`` (``P``'s, fitted offline) by one prepare's weight.

    >>> from tensordict import TensorDict
    >>> frames = torch.full((8, 10, 5), 10.0); frames[3:, :, 0] = 6.0           # slows from 10 to 6 m/s
    >>> tau = TensorDict({"action": torch.tensor([0, 4, 0, 0, 0, 0, 2, 0]), "next": {"frames": frames}}, [8])
    >>> round(read_prepared(tau, reaction=1.0, cruise=10.0, default=0.8), 2)    # (0.6 + 0.8) / 2
    0.7
    """
    frames = trajectory["next", "frames"]
    if not frames.numel():
        return default
    T = frames.shape[0]
    series, times = frame_series(frames, torch.arange(1.0, T + 1))  # step t starts at t s: its prompt is said then
    speed = series[:, FRAME_KEYS.index("speed")]
    action = trajectory["action"].reshape(-1).long().tolist()
    prepares, turns = {int(p) for p in PREPARES}, {int(t) for t in TURNS}
    effects, ends = [], []
    for t, a in enumerate(action):
        if a in prepares and not (t > 0 and action[t - 1] == a):  # a held prompt is not said again
            effects.append(t + AUDIO_DURATION[a] + reaction)
            ends.append(next((float(u) for u in range(t + 1, T) if action[u] in turns), math.inf))
    shares = prepare_shares(speed, times, effects, ends, cruise)
    return (sum(shares) + default) / (len(shares) + 1)


@dataclass(frozen=True)
class DriverPrior:
    """The meta model ``P``'s driver part: ``phi``'s centre and spread (``[log R, D]``), one prompt's log-SD
    ``sigma``, and the observation part's error rates: the detector's timing ``noise`` and share of misread answers
    ``outlier``; the probability ``hit`` that a late "turn" shows as a swerve or a miss, ``false`` that one in time
    seems to; the turn speed and braking the imagination uses where a drive shows none (:func:`read_response`); and
    the share of its speed a driver slows to on a "prepare" (fitted offline)."""

    mean: tuple[float, float]
    sd: tuple[float, float]
    sigma: float = 0.3
    noise: float = 0.15
    outlier: float = 0.3
    hit: float = 0.6
    false: float = 0.01
    turn_speed: float = 5.0
    brake: float = 2.0
    prepared: float = 0.75

    @classmethod
    def population(cls, log_r: tuple[float, float], decision: tuple[float, float], **rest: float) -> DriverPrior:
        """From the population's ``(mean, sd)`` of ``log R`` and of ``D``."""
        return cls((float(log_r[0]), float(decision[0])), (float(log_r[1]), float(decision[1])), **rest)

    @property
    def reaction_time(self) -> float:
        return math.exp(self.mean[0])

    def speeds(self) -> Response:
        """The driver's speeds where its drives show none (:func:`read_response`'s default)."""
        return Response(turn_speed=self.turn_speed, brake=self.brake, prepared=self.prepared)

    def centre(self) -> torch.Tensor:
        return torch.tensor(self.mean, dtype=torch.float64)

    def spread(self) -> torch.Tensor:
        return torch.tensor(self.sd, dtype=torch.float64)

    def to_dict(self) -> dict[str, Any]:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> DriverPrior:
        return cls(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items()})


@dataclass(frozen=True)
class Estimate:
    """``U``'s result: ``phi`` (``[log R, D]``), its spread (from the loss's curvature there) and whether the step
    was kept (``False``: no halving was at least as good on ``tau`` as the start, which is kept)."""

    phi: tuple[float, float]
    sd: tuple[float, float]
    stepped: bool = True

    @property
    def reaction_time(self) -> float:
        return math.exp(self.phi[0])

    @property
    def decision_time(self) -> float:
        return self.phi[1]


def nll(phi: torch.Tensor, evidence: Evidence, prior: DriverPrior) -> torch.Tensor:
    """The negative log-likelihood of ``evidence`` under ``phi`` (``[log R, D]``): the observation part of the model.

    An answer: the prompt takes effect in candidate frame ``k`` with probability ``(1 - outlier) f(d_k) DT``
    (``f`` lognormal around ``R``, log-SD ``sigma`` widened by the detector's ``noise``), or shows none in the window
    with ``outlier + (1 - outlier) P(d beyond it)``, weighed by the detector's reading. An outcome: the prompt was
    late (its delay beyond ``room`` at ``D``) shows as a swerve or miss with ``hit``, in time with ``false``."""
    log_r, decision = phi[0], phi[1]
    sigma = prior.sigma
    total = phi.new_zeros(())
    packed = evidence.packed()
    if packed["delays"] is not None:
        d, probs, last, none = packed["delays"], packed["probs"], packed["last"], packed["none"]
        s = math.sqrt(sigma**2 + prior.noise**2)
        mu = log_r - sigma**2 / 2
        z = (d.log() - mu) / s
        in_frame = torch.exp(-0.5 * z**2) / (s * d * math.sqrt(2 * math.pi)) * DT
        beyond = 0.5 * torch.erfc((last - mu) / (s * math.sqrt(2)))
        lik = (1 - prior.outlier) * (probs * in_frame).sum(1) + none * (prior.outlier + (1 - prior.outlier) * beyond)
        total = total - lik.clamp(min=1e-300).log().sum()
    if packed["room"] is not None:
        grid, room, late = DECISION_GRID.double(), packed["room"], packed["late"]
        x = decision.clamp(float(grid[0]), float(grid[-1]))
        i = int(torch.searchsorted(grid, x.detach().reshape(1)).clamp(1, len(grid) - 1)[0])
        r = room[:, i - 1] + (x - grid[i - 1]) / (grid[i] - grid[i - 1]) * (room[:, i] - room[:, i - 1])
        z = (torch.log(r.clamp(min=1e-3)) - (log_r - sigma**2 / 2)) / sigma
        p_late = torch.where(r > 0, 0.5 * torch.erfc(z / math.sqrt(2)), torch.ones_like(z))
        p_show = prior.false + (prior.hit - prior.false) * p_late
        total = total - torch.where(late, p_show, 1 - p_show).clamp(min=1e-300).log().sum()
    return total


def tau_loss(phi: torch.Tensor, evidence: Evidence, prior: DriverPrior, centre: torch.Tensor | None = None,
             spread: torch.Tensor | None = None) -> torch.Tensor:
    """``tau``'s loss under ``phi``: :func:`nll` plus the proximal term of the start ``(centre, spread)`` (``P``'s,
    or an earlier drive's estimate)."""
    centre = prior.centre() if centre is None else centre
    spread = prior.spread() if spread is None else spread
    return nll(phi, evidence, prior) + 0.5 * (((phi - centre) / spread) ** 2).sum()


def _newton(loss, start: torch.Tensor, floor: float, create_graph: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """One Newton step of ``loss`` from ``start``: ``(step, curvature)``, the curvature's eigenvalues lifted to at least
    ``floor`` (the proximal term's smallest: the step is never longer than the start's spread allows)."""
    with torch.enable_grad():  # also where a caller reads under no_grad (a tracker does)
        return _newton_step(loss, start, floor, create_graph)


def _newton_step(loss, start: torch.Tensor, floor: float, create_graph: bool) -> tuple[torch.Tensor, torch.Tensor]:
    # the point of evaluation is a copy of the start: where the loss's proximal term anchors at the same tensor
    # (meta-training), its derivative along the copy is the term's own, and the meta-gradient flows through both
    phi = start.clone() if create_graph else start.detach().requires_grad_(True)
    grad = torch.autograd.grad(loss(phi), phi, create_graph=True)[0]
    hess = torch.stack([torch.autograd.grad(grad[i], phi, retain_graph=True, create_graph=create_graph)[0]
                        for i in range(len(grad))])
    hess = 0.5 * (hess + hess.T)
    low = torch.linalg.eigvalsh(hess.detach())[0]
    if low < floor:  # not convex enough here (a reading in a tail of the likelihood): lift the curvature to the
        hess = hess + (floor - low) * torch.eye(len(grad), dtype=hess.dtype)  # start's own, a damped step
    step = -torch.linalg.solve(hess, grad if create_graph else grad.detach())
    return step, hess


def adapt_phi(prior: DriverPrior, evidence: Evidence, start: Estimate | None = None) -> Estimate:
    """``U(P, tau)``: one Newton step on :func:`tau_loss` from ``start`` (an earlier drive's estimate; default ``P``'s
    centre), halved until ``tau``'s loss is no worse than at the start (else the start is kept: ``stepped`` False).

    >>> prior = DriverPrior.population((0.2, 0.4), (2.0, 0.5))
    >>> adapt_phi(prior, Evidence()).phi == prior.mean      # nothing read: the start
    True
    """
    centre = prior.centre() if start is None else torch.tensor(start.phi, dtype=torch.float64)
    spread = prior.spread() if start is None else torch.tensor(start.sd, dtype=torch.float64)
    if len(evidence) == 0:
        return Estimate(tuple(centre.tolist()), tuple(spread.tolist()), stepped=False)

    def loss(phi: torch.Tensor) -> torch.Tensor:
        return tau_loss(phi, evidence, prior, centre, spread)

    floor = float((1 / spread**2).min())
    step, _ = _newton(loss, centre, floor)
    with torch.no_grad():
        before = float(loss(centre))
        phi, stepped = centre, False
        for _ in range(NEWTON_HALVINGS + 1):
            if float(loss(centre + step)) <= before:
                phi, stepped = centre + step, True
                break
            step = step / 2
    _, hess = _newton(loss, phi, floor)
    sd = torch.linalg.inv(hess).diagonal().clamp(min=MIN_SD**2).sqrt()
    return Estimate(tuple(phi.tolist()), tuple(sd.tolist()), stepped)


def meta_loss(prior: DriverPrior, rounds: list[tuple[Evidence, Evidence]]) -> float:
    """FTML's objective: the other drives' :func:`nll` under ``U(P, tau)`` (:func:`adapt_phi`, as a round adapts),
    per item of evidence, over every ``(tau, other drives)`` pair with evidence to score (``nan`` if none).

    >>> prior = DriverPrior.population((0.0, 0.4), (2.0, 0.5))
    >>> import math; math.isnan(meta_loss(prior, []))
    True
    """
    total, count = 0.0, 0
    for tau, other in rounds:
        if len(other) == 0:
            continue
        phi = torch.tensor(adapt_phi(prior, tau).phi, dtype=torch.float64)
        total += float(nll(phi, other, prior))
        count += len(other)
    return total / count if count else math.nan


def meta_train(prior: DriverPrior, rounds: list[tuple[Evidence, Evidence]], steps: int = 60, lr: float = 0.05,
               batch: int = 16, seed: int = 0) -> DriverPrior:
    """Follow-The-Meta-Leader on ``P``'s centre and spread: the minimizer, over every ``(tau, other drives)`` pair so
    far, of the other drives' :func:`nll` under ``U(P, tau)`` (differentiated through the Newton step), per item of
    evidence: ``steps`` Adam steps on ``batch`` pairs drawn (seeded) each step, every pair when there are fewer.
    Starts from ``prior``; pairs with no evidence to score are skipped. The result is kept only where it scores
    better than ``prior`` on every pair (:func:`meta_loss`), else ``prior`` is: a step on a few pairs at a time walks
    (Adam moves every step by about ``lr`` whatever the gradient's size) and can end worse over all of them (a look
    at one study's rounds: 2.10 to 2.38 per item over five rounds), so FTML never makes its own objective worse.

    >>> import torch
    >>> prior = DriverPrior.population((0.0, 0.4), (2.0, 0.5))
    >>> slow = Evidence(answers=[(torch.tensor([3.0, 3.1, 3.2]), torch.tensor([0.1, 0.8, 0.1]), 0.0)] * 2)
    >>> meta_train(prior, [(slow, slow)] * 3).mean[0] > prior.mean[0]     # the drivers so far are slow
    True
    """
    pairs = [(tau, other) for tau, other in rounds if len(other) > 0]
    if not pairs:
        return prior
    centre = prior.centre().clone().requires_grad_(True)
    log_spread = prior.spread().log().clone().requires_grad_(True)
    optimizer = torch.optim.Adam([centre, log_spread], lr=lr)
    generator = torch.Generator().manual_seed(int(seed))
    for _ in range(steps):
        spread = log_spread.exp().clamp(min=MIN_SD)
        total = centre.new_zeros(())
        chosen = pairs if len(pairs) <= batch else [
            pairs[int(i)] for i in torch.randperm(len(pairs), generator=generator)[:batch]]
        count = sum(len(other) for _, other in chosen)
        for tau, other in chosen:
            if len(tau) == 0:
                phi = centre
            else:
                step, _ = _newton(lambda p, tau=tau, spread=spread: tau_loss(p, tau, prior, centre, spread), centre,
                                  float((1 / spread.detach() ** 2).min()), create_graph=True)
                phi = centre + step
            total = total + nll(phi, other, prior)
        optimizer.zero_grad()
        (total / count).backward()
        optimizer.step()
    sd = log_spread.detach().exp().clamp(min=MIN_SD)
    trained = replace(prior, mean=tuple(centre.detach().tolist()), sd=tuple(sd.tolist()))
    return trained if meta_loss(trained, pairs) < meta_loss(prior, pairs) else prior


class DriverBelief:
    """The driver's estimate as a :class:`~pernav.learners.belief.BeliefTracker` reads a drive into it: ``P``, the
    estimate before this drive (``start``; ``None``: ``P``'s centre) and this drive's evidence; :attr:`estimate` is
    ``U`` from ``start`` on the drive so far (recomputed when evidence arrives). ``response``: the driver's speeds,
    read from its drives' frames (:func:`read_response`)."""

    decision = True  # the tracker reads the junctions' outcomes too

    def __init__(self, prior: DriverPrior, start: Estimate | None = None, adapt: bool = True,
                 response: Response | None = None) -> None:
        self.prior, self.start, self.adapt = prior, start, bool(adapt)
        self.response = response or prior.speeds()
        self.evidence = Evidence()
        self._estimate: Estimate | None = None

    # what the tracker calls
    def update(self, delays: torch.Tensor, probs: torch.Tensor, none: float) -> None:
        self.evidence.answers.append((delays.detach().double(), probs.detach().double(), float(none)))
        self._estimate = None

    def update_turn(self, room: torch.Tensor, late: bool) -> None:
        self.evidence.outcomes.append((room.detach().double(), bool(late)))
        self._estimate = None

    @property
    def estimate(self) -> Estimate:
        if self._estimate is None:
            if self.adapt:
                self._estimate = adapt_phi(self.prior, self.evidence, self.start)
            else:  # the ablation "without adaptation": the start (P's centre) whatever is read
                self._estimate = self.start or Estimate(self.prior.mean, self.prior.sd, stepped=False)
        return self._estimate

    def mean_reaction(self) -> float:
        return self.estimate.reaction_time

    @property
    def sd(self) -> float:
        return self.estimate.sd[0]

    def belief(self, guard: bool = True) -> dict[str, Any]:
        """Explore's timing for the env: the planner, not the rule, re-times the prompts."""
        return {}

    def drivers(self) -> list[DriverParams]:
        """The imagination's driver row: the estimate, one prompt's spread widened by the estimate's own (the
        predictive reaction time), the speeds and the slowing on a "prepare" read from the driver's drives."""
        e, r = self.estimate, self.response
        sigma = math.sqrt(self.prior.sigma**2 + e.sd[0] ** 2)
        return [DriverParams(e.reaction_time, max(e.decision_time, 0.1), sigma, r.turn_speed, r.brake, r.cruise,
                             prepared=r.prepared, accel=r.accel)]

    def formula(self) -> dict[str, Any]:
        """The belief's formula on this estimate (the ablation "planner replaced by the belief's formula"): explore's
        rule re-timed for the estimate's upper reaction time, when that is later than the average driver's."""
        e = self.estimate
        upper = math.exp(e.phi[0] + e.sd[0])
        return {"reaction_time": round(upper, 4)} if upper > explore_policy().driver.reaction_time else {}


class DriverTracker(BeliefTracker):
    """Reads a drive's answers and outcomes into a :class:`DriverBelief` (the frames and prompts only); ``copy``
    starts the next drive of the same driver from the estimate so far."""

    def __init__(self, detector: AnswerDetector, belief: DriverBelief, swerve: SwerveDetector | None = None,
                 formula: bool = False) -> None:
        super().__init__(detector, belief, guard=False, swerve=swerve)  # type: ignore[arg-type]
        self.formula = bool(formula)

    def fields(self) -> dict[str, Any]:
        return self.belief.formula() if self.formula else {}

    def copy(self) -> DriverTracker:
        """A tracker for another drive, from the same start (the evidence of a drive stays with it)."""
        belief = DriverBelief(self.belief.prior, self.belief.start, self.belief.adapt, self.belief.response)
        return DriverTracker(self.detector, belief, self.swerve, self.formula)

    def carried(self) -> Estimate:
        """The estimate after this drive: where the driver's next drive starts."""
        return self.belief.estimate


class DriverPlanner(TensorDictModuleBase):
    """The MPC policy of ``adapt_driver``: at each decision, the drive so far read into the tracker (the root's frames
    and the prompt played), then :class:`~pernav.planner.retiming.RetimingPlanner` on the hybrid model with the
    latest estimate. Make one per drive.

    Reads what the navigation env writes (``"history"``, ``"explore_future"``, ``"route_ahead"``, ``"action_mask"``,
    the step's ``"frames"``, ``"time"``, ``"played"``, ``"prompt_end"``, ``"distance_to_junction"``,
    ``"missed_turns"``); writes ``"action"``."""

    def __init__(self, tracker: DriverTracker, planner: dict[str, Any] | None = None) -> None:
        super().__init__()
        self.tracker = tracker
        self.env = DriverImaginedEnv(tracker.belief.drivers())
        options = dict(planner or {})
        departure = Departure(**options.pop("departure", {}))
        self.planner = RetimingPlanner(self.env, departure=departure, **options)
        self.in_keys = [*self.planner.in_keys, "frames", "time", "played", "prompt_end"]
        self.out_keys = ["action"]
        self._seen = -1.0
        self._last = 0
        self.planning_s = 0.0

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        now = float(td["time"])
        if now > self._seen and self._seen >= 0.0:  # a new step: its prompt and frames
            junction = float(td["distance_to_junction"]) if "distance_to_junction" in td.keys() else None
            missed = int(td["missed_turns"]) if "missed_turns" in td.keys() else None
            if self.tracker.observe(self._last, bool(td["played"]), float(td["prompt_end"]), td["frames"], now,
                                    junction, missed):
                self.env.drivers = self.tracker.belief.drivers()
        self._seen = now
        out = self.planner(td)
        self._last = int(out["action"])
        self.planning_s = self.planner.planning_s
        return out
