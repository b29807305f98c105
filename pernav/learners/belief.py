"""A belief about this driver from each prompt's answer: when the car began to slow or to change lane after a
"turn" or "prepare" prompt, read from the frames the navigation senses between decisions.

A heard prompt takes effect at its audio's end plus this prompt's reaction time, drawn lognormal around the driver's
mean reaction time ``R`` with a fixed coefficient of variation (:data:`pernav.world.drivers.REACTION_CV`). At that
frame the car's acceleration jumps (a "prepare" slows the car toward three quarters of its cruise, a "turn" brakes
for the turn) and a lane change makes the lane offset jump, unless a leader, a stop line or a junction already brakes
the car, or the prompt was misheard or ignored: then there is no answer to read. So the belief is built in two parts:

- :class:`AnswerDetector`, a small network that scores each frame of a prompt's answer window (its audio's end to
  :data:`ANSWER_SPAN` seconds later, or the next prompt) as the moment the prompt took effect, against "no visible
  answer". It is trained offline on simulated drivers of the population prior, whose moments are known (the paper's
  offline MDPs: :func:`pernav.learners.answers.labelled_drives`); at round time it sees the frames only.
- :class:`ReactionBelief`, an explicit likelihood on a grid of ``log R``: each answer contributes the lognormal
  density of its candidate delays weighted by the detector, mixed with a flat density for a prompt misread or
  unanswered. Its prior is the population's (fitted on the same offline drivers); the posterior narrows as answers
  accumulate, within a drive (:class:`BeliefTracker`, updated after each answered prompt) and across drives (the
  state carries over). Its spread never falls below the driver's own reading error (``drift``).
- With a :class:`DecisionPrior`, the posterior is joint over ``R`` and the decision time ``D``: each junction a "turn"
  prompt announced adds whether a swerve or a missed turn followed (:mod:`pernav.learners.outcomes`), whose likelihood
  under ``(R, D)`` is that the prompt took effect after the moment a driver with decision time ``D`` commits.

What the prompt rules act on is the posterior's ``quantile``-SD upper value when that is later than explore's
average driver (a late prompt costs far more than an early one), else explore's own timing; with the guard, the
quickest driver the posterior allows too; and a later decision time by as much as the evidence raised its upper value
(:meth:`ReactionBelief.belief`).

Example:
    >>> import torch
    >>> belief = ReactionBelief(prior_mean=0.3, prior_sd=0.4)
    >>> delays = torch.tensor([2.4, 2.5, 2.6])          # candidate delays (s after the audio) of one answer
    >>> for _ in range(5):                               # five answers, each clearly at ~2.5 s
    ...     belief.update(delays, torch.tensor([0.05, 0.9, 0.05]), none=0.0)
    >>> 2.2 < belief.mean_reaction() < 3.2 and belief.sd < 0.25
    True
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import torch
from torch import nn

from pernav.env.policies import explore_policy
from pernav.learners.outcomes import DECISION_GRID, SwerveDetector, turn_outcomes
from pernav.world.constants import PREPARES, SIDED, TURNS
from pernav.world.drivers import REACTION_CV

__all__ = ["ANSWERED", "ANSWER_SPAN", "N_FRAME_FEATURES", "Answer", "AnswerDetector", "BeliefTracker",
           "DecisionPrior", "ReactionBelief", "answers_of", "detectors", "frame_features", "frame_series",
           "late_probability"]

#: the prompts whose answer the belief reads: "turn" and "prepare" (left, right)
ANSWERED = SIDED
ANSWER_SPAN = 9.0  # s after a prompt's audio end in which its answer is looked for (reaction draws reach ~3x R)
EARLIEST = 0.25  # s after the audio end before which no answer is looked for
WINDOW = 3  # frames each side of a candidate frame that its features read
_CHANNELS = 6  # per frame: jump of acceleration, acceleration, lane-offset jump, speed/10, steering change, brake
N_FRAME_FEATURES = _CHANNELS * (2 * WINDOW + 1)
SIGMA = math.sqrt(math.log1p(REACTION_CV**2))  # SD of one prompt's log reaction time
DT = 0.1  # s between two frames (the world's 10 frames per one-second step)


def frame_series(frames: torch.Tensor, step_end: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The frames of ``T`` steps as one series: ``([T * F, C]`` frames, ``[T * F]`` their simulated times)``.

    ``frames``: ``[T, F, C]`` (the env's ``("next", "frames")``); ``step_end``: ``[T]`` the simulated time at each step's
    end (``("next", "time")``): frame ``j`` of a step lies ``(j + 1) / F`` s after its start.

    >>> series, times = frame_series(torch.zeros(2, 10, 5), torch.tensor([1.0, 2.0]))
    >>> series.shape, times[:2].tolist(), round(times[-1].item(), 3)
    (torch.Size([20, 5]), [0.10000000149011612, 0.20000000298023224], 2.0)
    """
    T, F, C = frames.shape
    offsets = torch.arange(1, F + 1, dtype=torch.float32) / F
    times = (step_end.float().reshape(T, 1) - 1.0) + offsets
    return frames.float().reshape(T * F, C), times.reshape(T * F)


def frame_features(series: torch.Tensor) -> torch.Tensor:
    """``[N, N_FRAME_FEATURES]``: for each frame of a ``[N, C]`` series (:data:`~pernav.env.navigation.FRAME_KEYS`),
    the jumps and levels of the frames around it that a prompt taking effect changes."""
    speed, acc, brake, steer, offset = series.unbind(-1)

    def jump(x: torch.Tensor) -> torch.Tensor:
        return torch.diff(x, prepend=x[:1])

    base = torch.stack([jump(acc), acc, jump(offset).abs().clamp(max=4.0), speed / 10.0, 5.0 * jump(steer), brake], -1)
    padded = torch.cat([base[:1].expand(WINDOW, -1), base, base[-1:].expand(WINDOW, -1)])
    return torch.cat([padded[k: k + len(base)] for k in range(2 * WINDOW + 1)], -1)


@dataclass
class Answer:
    """One heard prompt's answer window: its candidate frames' features, their delays after the audio's end."""

    instruction: int
    end: float  # simulated time the prompt's audio ended
    features: torch.Tensor  # [K, N_FRAME_FEATURES + 1]: the frames' and whether a later prompt may act there too
    delays: torch.Tensor  # [K] s after ``end``
    frame_times: torch.Tensor  # [K]

    @property
    def prepare(self) -> bool:
        return self.instruction in PREPARES


def answers_of(instructions: list[int], ends: list[float], series: torch.Tensor, times: torch.Tensor,
               features: torch.Tensor | None = None, complete: bool = True) -> list[Answer]:
    """The answer windows of the prompts played (``instructions`` and their audio ``ends``, in order) in a series.

    A window runs from ``EARLIEST`` after the audio's end to :data:`ANSWER_SPAN` after it, or to the audio's end of
    the next prompt of the same kind ("turn" or "prepare": it replaces this one); each candidate frame also carries
    whether the next prompt could act there too (it is past that prompt's audio end). With ``complete`` only windows
    the series covers to their end (and ``WINDOW`` frames beyond) are returned: a drive in progress waits for them.
    """
    features = frame_features(series) if features is None else features
    last = float(times[-1]) if len(times) else -1.0
    step = float(times[1] - times[0]) if len(times) > 1 else 0.1
    out = []
    for k, (instruction, end) in enumerate(zip(instructions, ends, strict=True)):
        if instruction not in ANSWERED:
            continue
        kind = instruction in PREPARES
        hi = end + ANSWER_SPAN
        same = [e for i, e in zip(instructions[k + 1:], ends[k + 1:], strict=True)
                if i in ANSWERED and (i in PREPARES) == kind]
        if same:
            hi = min(hi, same[0] + EARLIEST)
        other = ends[k + 1] + EARLIEST if k + 1 < len(ends) else math.inf
        if complete and last < hi + WINDOW * step - 1e-6:
            continue
        idx = torch.nonzero((times > end + EARLIEST) & (times <= hi)).reshape(-1)
        if len(idx) == 0:
            continue
        shared = (times[idx] > other).float().reshape(-1, 1)
        out.append(Answer(int(instruction), float(end), torch.cat([features[idx], shared], 1), times[idx] - end,
                          times[idx]))
    return out


class AnswerDetector(nn.Module):
    """Scores each candidate frame of an answer window as the moment the prompt took effect, against a learned
    "no visible answer" (one per kind of prompt): ``forward`` gives ``[K + 1]`` log-probabilities, the last "none".

    Fitted by :meth:`fit` on windows whose moment is known (the frame index, or ``-1``: none in the window).
    """

    def __init__(self, hidden: int = 32) -> None:
        super().__init__()
        self.net = nn.Sequential(nn.Linear(N_FRAME_FEATURES + 2, hidden), nn.Tanh(), nn.Linear(hidden, 1))
        self.none = nn.Parameter(torch.zeros(2))  # "turn", "prepare"
        self.register_buffer("mean", torch.zeros(N_FRAME_FEATURES + 1))
        self.register_buffer("scale", torch.ones(N_FRAME_FEATURES + 1))

    def _scores(self, features: torch.Tensor, prepare: torch.Tensor) -> torch.Tensor:
        x = (features - self.mean) / self.scale
        kind = prepare.float().reshape(*prepare.shape, *([1] * (x.dim() - prepare.dim() - 1)), 1)
        return self.net(torch.cat([x, kind.expand(*x.shape[:-1], 1)], -1)).squeeze(-1)

    def forward(self, features: torch.Tensor, prepare: bool) -> torch.Tensor:
        """``[K + 1]`` log-probabilities of the ``K`` candidate frames (``[K, N_FRAME_FEATURES + 1]``) and of "none"."""
        kind = torch.tensor(bool(prepare))
        scores = self._scores(features, kind)
        return torch.log_softmax(torch.cat([scores, self.none[int(prepare)].reshape(1)]), 0)

    def fit(self, answers: list[Answer], labels: list[int], epochs: int = 300, lr: float = 1e-2,
            seed: int = 0) -> AnswerDetector:
        """Fit on answer windows and their true frame (``-1``: the prompt took no effect inside the window), all at
        once (padded), full-batch Adam."""
        if not answers or len(answers) != len(labels):
            raise ValueError(f"need answers with one label each; got {len(answers)} and {len(labels)}")
        with torch.random.fork_rng():  # the same fit in any process, and the caller's random stream left alone
            torch.manual_seed(seed)
            for layer in self.net:  # a fresh, seeded start: the weights drawn at construction depend on the caller
                if isinstance(layer, nn.Linear):
                    layer.reset_parameters()
            with torch.no_grad():
                self.none.zero_()
            return self._fit(answers, labels, epochs, lr)

    def _fit(self, answers: list[Answer], labels: list[int], epochs: int, lr: float) -> AnswerDetector:
        K = max(len(a.delays) for a in answers)
        X = torch.zeros(len(answers), K, N_FRAME_FEATURES + 1)
        mask = torch.zeros(len(answers), K, dtype=torch.bool)
        for i, a in enumerate(answers):
            X[i, : len(a.delays)], mask[i, : len(a.delays)] = a.features, True
        allf = torch.cat([a.features for a in answers])
        self.mean.copy_(allf.mean(0))
        self.scale.copy_(allf.std(0).clamp(min=1e-3))
        prepare = torch.tensor([a.prepare for a in answers])
        target = torch.tensor([lab if lab >= 0 else K for lab in labels])
        optimizer = torch.optim.Adam(self.parameters(), lr=lr)
        for _ in range(epochs):
            scores = self._scores(X, prepare).masked_fill(~mask, -1e9)
            logits = torch.cat([scores, self.none[prepare.long()].reshape(-1, 1)], 1)
            loss = nn.functional.cross_entropy(logits, target)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
        self.final_loss = float(loss.detach())
        return self


class ReactionBelief:
    """A posterior over the driver's mean reaction time ``R`` on a grid of ``log R``, and, given a ``decision`` prior,
    jointly over its decision time ``D`` (s before a junction at which it commits to a branch) on a grid of ``D``.

    Args:
        prior_mean, prior_sd: the population prior of ``log R`` (normal).
        noise: SD (log s) of the detector's timing beside the prompt's own draw; ``outlier``: the share of answers read
            from a frame that is not the prompt's (both fitted for coverage on development drivers).
        quantile: posterior SDs above the mean that the prompt rules act on.
        decision: ``None`` (``D`` not tracked) or the population prior of ``D`` and how its outcomes show
            (:class:`DecisionPrior`).
        drift: SD (log s) of a driver's own reading error: the frames of one driver (its vehicle, its way of braking)
            may read its answers earlier or later by the same factor in every drive, so the posterior about ``R``
            never narrows below it (the likelihood is smoothed along ``log R`` by it; fitted for the interval's
            coverage on development drivers). 0: every answer's error independent.
        slower: the posterior probability that ``R`` exceeds the average driver's that the evidence must reach before
            the prompts are re-timed for the reaction time; below it they keep explore's. 0: the upper value alone
            decides (a driver the evidence shows to be quicker than average, but with a wide posterior, was re-timed).
    """

    GRID = torch.linspace(math.log(0.3), math.log(6.0), 241, dtype=torch.float64)
    D_GRID = DECISION_GRID

    def __init__(self, prior_mean: float, prior_sd: float, noise: float = 0.15, outlier: float = 0.3,
                 quantile: float = 1.0, decision: DecisionPrior | None = None, drift: float = 0.0,
                 slower: float = 0.0) -> None:
        self.prior_mean, self.prior_sd = float(prior_mean), float(prior_sd)
        self.noise, self.outlier, self.quantile = float(noise), float(outlier), float(quantile)
        self.decision, self.drift, self.slower = decision, float(drift), float(slower)
        # the prior times every answer's and outcome's likelihood (without the driver's own reading error)
        self.log_post = self._log_prior()
        if decision is not None:  # [G, H]: log R by D
            self.log_post = self.log_post[:, None] + decision.log_prior(self.D_GRID)[None]
        self.answers = 0
        self.outcomes = 0

    # ----- evidence ------------------------------------------------------------------------------
    def update(self, delays: torch.Tensor, probs: torch.Tensor, none: float) -> None:
        """One answer: candidate frames at ``delays`` (s after the audio's end, ``DT`` apart) with the detector's
        ``probs`` for each, and its probability ``none`` of no visible answer in the window.

        Under ``R`` the prompt takes effect in frame ``k`` with probability ``(1 - outlier) f(d_k | R) DT`` (``f`` the
        lognormal of one prompt's delay, widened by the detector's ``noise``), and shows no answer in the window with
        probability ``outlier + (1 - outlier) P(d > window | R)``: a slow driver's answer falls beyond the window (the
        next prompt's) more often, and that too is evidence. The likelihood weighs both by what the detector read."""
        d = delays.double().clamp(min=0.05)
        s = math.sqrt(SIGMA**2 + self.noise**2)
        mu = self.GRID[:, None] - SIGMA**2 / 2
        z = (d.log()[None] - mu) / s
        in_frame = torch.exp(-0.5 * z**2) / (s * d[None] * math.sqrt(2 * math.pi)) * DT  # [G, K]
        beyond = 0.5 * torch.erfc((math.log(float(d[-1]) + DT / 2) - mu[:, 0]) / (s * math.sqrt(2)))  # [G]
        likelihood = ((1 - self.outlier) * (probs.double()[None] * in_frame).sum(1)
                      + none * (self.outlier + (1 - self.outlier) * beyond))
        log_l = likelihood.clamp(min=1e-300).log()
        self.log_post = self.log_post + (log_l if self.log_post.dim() == 1 else log_l[:, None])
        self.answers += 1

    def update_turn(self, room: torch.Tensor, late: bool) -> None:
        """One announced junction's outcome (:class:`~pernav.learners.outcomes.TurnOutcome`): ``room`` ``[H]``, for each
        decision time of :attr:`D_GRID`, the time from its first "turn" prompt's audio end to that driver's commit, and
        whether a swerve or a miss followed (``late``).

        The prompt is late when its delay (lognormal around ``R``) exceeds ``room``; a late prompt shows as a swerve or
        a miss with probability ``hit`` (not when a followed "prepare" had already chosen the branch), an in-time one
        with probability ``false`` (:class:`DecisionPrior`, fitted offline). No-op without a decision prior."""
        if self.decision is None:
            return
        p_late = late_probability(self.GRID, room)  # [G, H]
        p_show = self.decision.false + (self.decision.hit - self.decision.false) * p_late
        self.log_post = self.log_post + (p_show if late else 1 - p_show).clamp(min=1e-300).log()
        self.outcomes += 1

    # ----- what it says --------------------------------------------------------------------------
    def _log_prior(self) -> torch.Tensor:
        return -0.5 * ((self.GRID - self.prior_mean) / self.prior_sd) ** 2

    def joint(self) -> torch.Tensor:
        """The posterior's weights: ``[G]`` over ``log R``, or ``[G, H]`` over ``log R`` by ``D``."""
        if self.drift > 0.0:  # the prior times the likelihood smoothed along log R by the driver's reading error
            prior = self._log_prior()
            prior = prior if self.log_post.dim() == 1 else prior[:, None]
            likelihood = self.log_post - prior
            w = torch.exp(prior - prior.max()) * (_drift_kernel(self.drift) @ torch.exp(likelihood - likelihood.max()))
        else:
            w = torch.exp(self.log_post - self.log_post.max())
        return w / w.sum()

    def weights(self) -> torch.Tensor:
        """The posterior's weights over ``log R`` (``[G]``; ``D`` summed out)."""
        w = self.joint()
        return w if w.dim() == 1 else w.sum(1)

    def decision_weights(self) -> torch.Tensor:
        """The posterior's weights over ``D`` (``[H]``); raises without a decision prior."""
        if self.decision is None:
            raise ValueError("this belief tracks no decision time (no decision prior)")
        return self.joint().sum(0)

    @property
    def mean(self) -> float:
        """Posterior mean of ``log R``."""
        return _moments(self.weights(), self.GRID)[0]

    @property
    def sd(self) -> float:
        """Posterior SD of ``log R`` (narrows as answers accumulate)."""
        return _moments(self.weights(), self.GRID)[1]

    @property
    def decision_mean(self) -> float:
        """Posterior mean of ``D`` (s)."""
        return _moments(self.decision_weights(), self.D_GRID)[0]

    @property
    def decision_sd(self) -> float:
        """Posterior SD of ``D`` (s)."""
        return _moments(self.decision_weights(), self.D_GRID)[1]

    def mean_reaction(self) -> float:
        """The posterior median of ``R`` (s): ``exp`` of the mean of ``log R``."""
        return math.exp(self.mean)

    def slower_than(self, reaction_time: float) -> float:
        """The posterior probability that ``R`` exceeds ``reaction_time`` (s)."""
        return _mass_above(self.weights(), self.GRID, math.log(reaction_time))

    def interval(self, level: float = 0.9) -> tuple[float, float]:
        """The central ``level`` credible interval of ``R`` (s)."""
        lo, hi = _central(self.weights(), self.GRID, level)
        return math.exp(lo), math.exp(hi)

    def decision_interval(self, level: float = 0.9) -> tuple[float, float]:
        """The central ``level`` credible interval of ``D`` (s)."""
        return _central(self.decision_weights(), self.D_GRID, level)

    def belief(self, guard: bool = True) -> dict[str, Any]:
        """What the prompt rules act on (:func:`pernav.env.policies.belief_policy`).

        The reaction time: explore's timing (no entry) when the posterior's upper value (``quantile`` SDs above the
        mean) is no later than explore's average driver's, or when the posterior probability that the driver is slower
        than that driver is below ``slower``; else that upper value and, with ``guard``, the quickest
        driver the posterior allows (its lower value, never slower than the average driver, at the 5th percentile of
        one prompt's draw). The decision time (with a decision prior): explore's average driver's, later by as much
        as the posterior's upper value of ``D`` has risen above the prior's; turn outcomes that show no lateness
        never make it earlier than explore's."""
        average = explore_policy().driver
        belief: dict[str, Any] = {}
        joint = self.joint()  # once: each moment below would otherwise smooth and normalize the posterior again
        w = joint if joint.dim() == 1 else joint.sum(1)
        mean, sd = _moments(w, self.GRID)
        upper = math.exp(mean + self.quantile * sd)
        if upper > average.reaction_time and _mass_above(w, self.GRID, math.log(average.reaction_time)) >= self.slower:
            belief["reaction_time"] = round(upper, 4)
            if guard:
                low = min(math.exp(mean - self.quantile * sd), average.reaction_time)
                quick = dataclasses.replace(average, reaction_time=low)
                belief["fastest"] = {"reaction_time": round(quick.reaction_draw(-1.645), 4),
                                     "decision_time": average.decision_time}
        if self.decision is not None and self.outcomes:
            d_mean, d_sd = _moments(joint.sum(0), self.D_GRID)
            rise = (d_mean + self.quantile * d_sd) - self.decision.upper(self.quantile)
            if rise > 0.0:
                belief["decision_time"] = round(average.decision_time + rise, 4)
        return belief

    def state_dict(self) -> dict[str, Any]:
        return {"prior_mean": self.prior_mean, "prior_sd": self.prior_sd, "noise": self.noise,
                "outlier": self.outlier, "quantile": self.quantile, "log_post": self.log_post.clone(),
                "answers": self.answers, "outcomes": self.outcomes, "drift": self.drift, "slower": self.slower,
                "decision": None if self.decision is None else dataclasses.asdict(self.decision)}

    @classmethod
    def from_state_dict(cls, state: Mapping[str, Any]) -> ReactionBelief:
        decision = state.get("decision")
        out = cls(state["prior_mean"], state["prior_sd"], state["noise"], state["outlier"], state["quantile"],
                  None if decision is None else DecisionPrior(**decision), float(state.get("drift", 0.0)),
                  float(state.get("slower", 0.0)))
        out.log_post, out.answers = state["log_post"].clone(), int(state["answers"])
        out.outcomes = int(state.get("outcomes", 0))
        return out


def detectors(model: Mapping[str, Any]) -> tuple[AnswerDetector, SwerveDetector | None]:
    """The answer detector and the swerve detector (``None`` where ``model["swerve"]`` is absent or ``None``) of a
    study's fitted belief (``{"detector", "swerve", ...}``: state dicts)."""
    detector = AnswerDetector()
    detector.load_state_dict(model["detector"])
    swerve = None
    if model.get("swerve") is not None:
        swerve = SwerveDetector()
        swerve.load_state_dict(model["swerve"])
    return detector, swerve


def late_probability(log_r: torch.Tensor, room: torch.Tensor) -> torch.Tensor:
    """``[G, H]``: the probability that a prompt's delay (lognormal around ``exp(log_r)``, one prompt's draw) exceeds
    each ``room`` (s; at or below zero: certainly)."""
    mu = log_r.double()[:, None] - SIGMA**2 / 2
    room = room.double()[None]
    z = (room.clamp(min=1e-3).log() - mu) / SIGMA
    return torch.where(room > 0, 0.5 * torch.erfc(z / math.sqrt(2)), torch.ones_like(z))


@functools.lru_cache(maxsize=4)
def _drift_kernel(drift: float) -> torch.Tensor:
    """``[G, G]``: row ``i`` the normal density (SD ``drift``) of a read ``log R`` around grid point ``i``, normalized
    on the grid."""
    grid = ReactionBelief.GRID
    k = torch.exp(-0.5 * ((grid[None] - grid[:, None]) / drift) ** 2)
    return k / k.sum(1, keepdim=True)


def _moments(weights: torch.Tensor, grid: torch.Tensor) -> tuple[float, float]:
    """Mean and SD of a distribution on a grid."""
    mean = float((weights * grid).sum())
    return mean, float(((weights * (grid - mean) ** 2).sum()).sqrt())


def _mass_above(weights: torch.Tensor, grid: torch.Tensor, value: float) -> float:
    """The probability mass of a distribution on a grid above ``value``."""
    return float(weights[grid > value].sum())


def _central(weights: torch.Tensor, grid: torch.Tensor, level: float) -> tuple[float, float]:
    """The central ``level`` interval of a distribution on a grid (its grid points)."""
    c = torch.cumsum(weights, 0)
    lo = int(torch.searchsorted(c, torch.tensor((1 - level) / 2, dtype=c.dtype)))
    hi = int(torch.searchsorted(c, torch.tensor((1 + level) / 2, dtype=c.dtype)))
    return float(grid[min(lo, len(grid) - 1)]), float(grid[min(hi, len(grid) - 1)])


@dataclass(frozen=True)
class DecisionPrior:
    """The population prior of the decision time ``D`` (normal, s) and how a "turn" prompt's lateness shows, all
    fitted offline on simulated drivers (:func:`pernav.learners.answers.fit_belief`): ``hit``, the probability that a
    prompt past the commit point shows a swerve or a miss; ``false``, that an in-time one seems to.

    >>> prior = DecisionPrior(mean=2.0, sd=0.6, hit=0.6, false=0.01)
    >>> round(prior.upper(1.0), 2)
    2.6
    """

    mean: float
    sd: float
    hit: float
    false: float

    def log_prior(self, grid: torch.Tensor) -> torch.Tensor:
        return -0.5 * ((grid - self.mean) / self.sd) ** 2

    def upper(self, quantile: float) -> float:
        """The prior's mean plus ``quantile`` SDs, on :attr:`ReactionBelief.D_GRID` (where the grid cuts it)."""
        w = torch.exp(self.log_prior(ReactionBelief.D_GRID))
        mean, sd = _moments(w / w.sum(), ReactionBelief.D_GRID)
        return mean + quantile * sd


class BeliefTracker:
    """The belief about the driver of one drive, updated after each answered prompt as the drive goes on: what
    :class:`~pernav.env.navigation.NavigationEnv` calls after every step when its ``config["belief"]`` is one (the
    env's :class:`~pernav.env.policies.BeliefSource`). Reads the step's played prompt and the car's frames only.

    >>> tracker = BeliefTracker(AnswerDetector(), ReactionBelief(0.3, 0.4))
    >>> round(tracker.fields()["reaction_time"], 1)  # no answer read yet: the prior's upper value, exp(0.3 + 0.4)
    2.0
    """

    def __init__(self, detector: AnswerDetector, belief: ReactionBelief, guard: bool = True,
                 swerve: SwerveDetector | None = None) -> None:
        self.detector, self.belief, self.guard, self.swerve = detector, belief, bool(guard), swerve
        self.reset()

    def reset(self) -> None:
        """Start a new drive (the belief carries over; the drive's frames and prompts do not)."""
        self.frames: list[torch.Tensor] = []
        self.ends: list[float] = []
        self.junction: list[float] = []  # per step: distance to the next decision junction after it (m)
        self.missed: list[float] = []  # per step: the navigation's missed-turn count after it
        self.prompts: list[tuple[int, float]] = []  # (instruction, audio end) played
        self.read: set[float] = set()  # audio ends of the prompts whose answer was read
        self.judged: set[float] = set()  # audio ends of the "turn" prompts whose junction's outcome was read
        self.passed: set[int] = set()  # steps in which the car passed a junction whose outcome was read
        self.trace: list[tuple[float, float, float]] = []  # (time, mean R, sd of log R) after each update

    def observe(self, instruction: int, played: bool, prompt_end: float, frames: Any, step_end: float,
                junction: float | None = None, missed: int | None = None) -> bool:
        """One step: the action's instruction, whether it played, its audio's end, the step's frames ``[F, C]``, the
        simulated time at its end and, for the decision time, the distance to the next decision junction after it
        and the navigation's missed-turn count. Reads every answer whose window has closed and every announced
        junction's outcome once it shows; True when the belief moved."""
        if played:
            self.prompts.append((int(instruction), float(prompt_end)))
        self.frames.append(torch.as_tensor(frames, dtype=torch.float32))
        self.ends.append(float(step_end))
        self.junction.append(math.inf if junction is None else float(junction))
        self.missed.append(0.0 if missed is None else float(missed))
        moved = self._read(complete=True)
        return self._judge(complete=True) or moved

    def finish(self) -> bool:
        """The drive ended: read the answers whose window the drive cut short, and the junctions' outcomes."""
        moved = self._read(complete=False)
        return self._judge(complete=False) or moved

    def observe_drive(self, trajectory: Any) -> None:
        """Read a whole ``[T]`` drive (a tau: the env's ``("next", ...)`` entries of what it played and sensed) as a
        new drive of this driver."""
        self.reset()
        step = trajectory["next"]
        outcomes = self.swerve is not None and "distance_to_junction" in step.keys()
        for t in range(trajectory.shape[0]):
            self.observe(int(trajectory["action"][t]), bool(step["played"][t]), float(step["prompt_end"][t]),
                         step["frames"][t], float(step["time"][t]),
                         float(step["distance_to_junction"][t]) if outcomes else None,
                         int(step["missed_turns"][t]) if outcomes else None)
        self.finish()

    def _judge(self, complete: bool) -> bool:
        """The outcome of each junction announced by a "turn" prompt (:func:`~pernav.learners.outcomes.turn_outcomes`)."""
        if self.swerve is None or self.belief.decision is None or math.isinf(self.junction[-1] if self.junction else 0):
            return False
        pending = [(i, e) for i, e in self.prompts if i in TURNS and e not in self.judged]
        if not pending:
            return False
        start = max(next((t for t, end in enumerate(self.ends) if end > pending[0][1]), len(self.ends)) - 1, 0)
        frames = torch.stack(self.frames[start:])
        with torch.no_grad():
            swerve = self.swerve(frames)
        outcomes = turn_outcomes(pending, torch.tensor(self.ends[start:]), torch.tensor(self.junction[start:]),
                                 torch.tensor(self.missed[start:]), swerve, frames, complete=complete)
        moved = False
        for outcome in outcomes:
            self.judged.add(outcome.end)
            if outcome.step + start in self.passed:  # a later prompt for a junction already judged
                continue
            self.passed.add(outcome.step + start)
            self.belief.update_turn(outcome.room, outcome.late)
            self.trace.append((float(self.ends[-1]), self.belief.mean_reaction(), self.belief.sd))
            moved = True
        return moved

    def _read(self, complete: bool) -> bool:
        pending = [k for k, (i, e) in enumerate(self.prompts) if i in ANSWERED and e not in self.read]
        if not self.frames or not pending:
            return False
        # only the steps from the first unread prompt on (its window and the frames its features look back on)
        first = self.prompts[pending[0]][1]
        start = next((t for t, end in enumerate(self.ends) if end >= first - 1.0), len(self.ends) - 1)
        series, times = frame_series(torch.stack(self.frames[start:]), torch.tensor(self.ends[start:]))
        instructions, ends = zip(*self.prompts[pending[0]:], strict=True)
        answers = answers_of(list(instructions), list(ends), series, times, complete=complete)
        new = [a for a in answers if a.end not in self.read]
        moved = False
        with torch.no_grad():
            for answer in new:
                logp = self.detector(answer.features, answer.prepare).exp()
                self.belief.update(answer.delays, logp[:-1], float(logp[-1]))
                self.trace.append((float(times[-1]), self.belief.mean_reaction(), self.belief.sd))
                self.read.add(answer.end)
                moved = True
        return moved

    def fields(self) -> dict[str, Any]:
        return self.belief.belief(self.guard)

    @classmethod
    def from_model(cls, model: Mapping[str, Any], guard: bool = True,
                   posterior: Mapping[str, Any] | None = None) -> BeliefTracker:
        """A tracker from a study's fitted belief (``{"detector", "prior", "swerve"}``: state dicts; ``swerve`` may be
        ``None`` or absent), starting from ``posterior`` (a :class:`ReactionBelief` state dict) or the prior."""
        detector, swerve = detectors(model)
        belief = ReactionBelief.from_state_dict(model["prior"] if posterior is None else posterior)
        return cls(detector, belief, guard=guard, swerve=swerve)

    def copy(self) -> BeliefTracker:
        """A copy for another drive of the same driver (the detector is shared: it does not change)."""
        out = copy.copy(self)
        out.belief = ReactionBelief.from_state_dict(self.belief.state_dict())
        out.reset()
        return out
