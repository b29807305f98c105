"""``adapt_driver`` in a study (:mod:`pernav.learners.driver`): its offline phase, each online round's ``U(P, tau)``,
its Follow-The-Meta-Leader update, its ablations, and ``best_shift``, the reference every gap is measured against.

Methods:

* ``adapt_driver``: the meta model ``P`` (meta-trained offline on simulated population drivers, then by FTML after
  every online round), ``U(P, tau)`` on the round's explore drive (from this user's earlier estimate when it drove
  before), updated within each drive, MPC tree search on the hybrid model;
* ``adapt_driver_static``: without adaptation (the meta model's centre alone, in every drive);
* ``adapt_driver_prior``: without meta-learning (``P`` the population's statistics, never meta-trained);
* ``adapt_driver_formula``: ``adapt_driver``'s estimate, but the prompts re-timed by the belief's formula instead of
  the planner;
* ``best_shift``: explore's rule shifted by the constant number of steps (:data:`SHIFTS`) that is cheapest for this
  round's user on the true simulator, chosen on selection episodes whose seeds differ from the evaluation's (so that
  the minimum of noisy costs does not flatter it), then evaluated on the round's episodes.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import torch

from pernav.env.navigation import FRAME_KEYS
from pernav.learners.answers import LabelledDrive
from pernav.learners.belief import AnswerDetector, detectors, frame_series
from pernav.learners.driver import (
    CRUISE_QUANTILE,
    DriverBelief,
    DriverPrior,
    DriverTracker,
    Estimate,
    Evidence,
    Response,
    meta_loss,
    meta_train,
    prepare_shares,
    read_response,
)
from pernav.learners.outcomes import SwerveDetector
from pernav.model.driver import DriverParams
from pernav.study.report import running_mean
from pernav.world.constants import PREPARES, TURNS

__all__ = ["DRIVER_METHODS", "DRIVER_PLANNER", "SHIFTS", "DriverState", "fit_driver"]

DRIVER_METHODS = ("adapt_driver", "adapt_driver_static", "adapt_driver_prior", "adapt_driver_formula")
#: the constant shifts (steps; > 0 earlier) best_shift chooses from: as far back as the env's plan reaches, 3 ahead
SHIFTS = (-2, -1, 0, 1, 2, 3)
#: adapt_driver's planner: the re-timing tree search both ways (earlier and later), leaving explore for the expected
#: cost over the predictive reaction quantiles (a fifth of the rows must each see the gain) where waiting a step (the
#: cheapest candidate that plays explore's action now) costs more; its fine choices keep explore's order (no "turn"
#: said while explore's "prepare" is still to come)
DRIVER_PLANNER: dict[str, Any] = {"horizon": 16, "advance": 8, "delay": 2, "in_order": True,
                                  "departure": {"margin": 10.0, "rel_margin": 0.02, "agree": 0.2, "max_spread": None,
                                                "wait": True}}


def _sigma(drives: list[LabelledDrive]) -> float:
    """One prompt's log-SD of its reaction delay around its driver's, from the offline drives' labelled answers."""
    logs = []
    for d in drives:
        own = [math.log(float(a.delays[k])) for a, k in zip(d.answers, d.labels, strict=True) if k >= 0]
        if len(own) >= 2:
            mean = sum(own) / len(own)
            logs += [x - mean for x in own]
    return float(torch.tensor(logs).std()) if len(logs) > 2 else 0.3


def _prepared(drives: list[LabelledDrive]) -> float:
    """The share of its cruise a driver drives at after a "prepare", averaged over the offline drives' prepares
    (:func:`~pernav.learners.driver.prepare_shares`, as a round reads ``tau``, but from when each took effect, which
    is labelled here); a "prepare" that never took effect (misheard, ignored) slows nothing."""
    prepares, turns = [int(p) for p in PREPARES], [int(t) for t in TURNS]
    shares: list[float] = []
    for d in drives:
        series, times = frame_series(torch.from_numpy(np.stack([s["frames"] for s in d.steps])),
                                     torch.tensor([s["time"] for s in d.steps]))
        speed = series[:, FRAME_KEYS.index("speed")]
        cruise = float(speed.quantile(CRUISE_QUANTILE))
        played = [s for s in d.steps if s["played"]]
        effects, ends = [], []
        for i, step in enumerate(played):
            if step["instruction"] not in prepares:
                continue
            effect = d.took_effect.get(step["prompt_end"])
            if effect is None:
                shares.append(1.0)
                continue
            # the "turn" is said at its step's start, a second before that step's end
            effects.append(effect)
            ends.append(next((q["time"] - 1.0 for q in played[i + 1:] if q["instruction"] in turns), math.inf))
        shares += prepare_shares(speed.double(), times.double(), effects, ends, cruise)
    return sum(shares) / len(shares) if shares else DriverParams().prepared


def labelled_evidence(drive: LabelledDrive, prior: DriverPrior, detector: AnswerDetector,
                      swerve: SwerveDetector | None) -> Evidence:
    """What ``U`` reads from an offline drive (its answers and junction outcomes), as a round reads ``tau``."""
    belief = DriverBelief(prior)
    tracker = DriverTracker(detector, belief, swerve)
    tracker.reset()
    for step in drive.steps:
        tracker.observe(step["instruction"], step["played"], step["prompt_end"], step["frames"], step["time"],
                        step["junction"], step["missed"])
    tracker.finish()
    return belief.evidence


def fit_driver(drives: list[LabelledDrive], belief_model: dict[str, Any], noise: float, outlier: float
               ) -> dict[str, Any]:
    """The offline phase: ``P0``, the population's statistics (its drivers' ``log R`` and ``D``, known: they are
    simulated; one prompt's spread and the slowing on a "prepare" from their labelled answers; the belief's detectors
    and error rates), and ``P``,
    ``P0`` meta-trained on the same drivers (each drive's first half adapts, its second half scores)."""
    prior = belief_model["prior"]
    decision = prior["decision"]
    log_r = torch.tensor([math.log(d.reaction_time) for d in drives], dtype=torch.float64)
    D = torch.tensor([d.decision_time for d in drives], dtype=torch.float64)
    p0 = DriverPrior((float(log_r.mean()), float(D.mean())), (float(log_r.std()), float(D.std())),
                     sigma=_sigma(drives), noise=noise, outlier=outlier, hit=float(decision["hit"]),
                     false=float(decision["false"]), prepared=_prepared(drives))
    detector, swerve = detectors(belief_model)
    pairs = [labelled_evidence(d, p0, detector, swerve).halves() for d in drives]
    meta = meta_train(p0, pairs)
    return {"detector": belief_model["detector"], "swerve": belief_model["swerve"], "prior0": p0.to_dict(),
            "prior": meta.to_dict(), "offline_pairs": [(a.state(), b.state()) for a, b in pairs]}


class DriverState:
    """The learner's state in a run (a checkpoint keeps :meth:`to_dict`): the offline fit, the meta model ``P``, the
    online rounds' ``(tau, other drives)`` evidence, each user's estimate (per ablation) and what it read per round."""

    def __init__(self, data: dict[str, Any]) -> None:
        self.data = data
        data.setdefault("online_pairs", [])
        data.setdefault("estimates", {})
        data.setdefault("rounds", {})
        self.detector, self.swerve = detectors(data)

    def to_dict(self) -> dict[str, Any]:
        return self.data

    def prior(self, method: str) -> DriverPrior:
        return DriverPrior.from_dict(self.data["prior0" if method == "adapt_driver_prior" else "prior"])

    def tracker(self, method: str, start: Estimate | None, response: Response) -> DriverTracker:
        belief = DriverBelief(self.prior(method), start, adapt=method != "adapt_driver_static", response=response)
        return DriverTracker(self.detector, belief, self.swerve, formula=method == "adapt_driver_formula")

    def read_tau(self, user: str, label: str, tau: Any, methods: list[str]) -> dict[str, DriverTracker]:
        """Each method's tracker for the round's episodes: ``U`` on ``tau`` from this user's estimate so far (the
        meta model's centre on a first drive), and the evidence ``tau`` gave (kept for the meta update)."""
        # the slowing on a "prepare" is read with the reaction time known before this drive (this user's estimate so far,
        # else P's centre): tau's own answers are what U then reads
        saved = self.data["estimates"].get("adapt_driver", {}).get(user)
        known = Estimate(**saved).reaction_time if saved else self.prior("adapt_driver").reaction_time
        response = read_response(tau, self.prior("adapt_driver").speeds(), reaction=known)
        chains = {"adapt_driver_prior" if m == "adapt_driver_prior" else "adapt_driver"
                  for m in methods if m != "adapt_driver_static"}
        estimates: dict[str, Estimate] = {}
        for key in sorted(chains):
            saved = self.data["estimates"].get(key, {}).get(user)
            reader = self.tracker(key, Estimate(**saved) if saved else None, response)
            reader.observe_drive(tau)
            estimates[key] = estimate = reader.carried()
            self.data["estimates"].setdefault(key, {})[user] = {"phi": estimate.phi, "sd": estimate.sd,
                                                               "stepped": estimate.stepped}
            if key == "adapt_driver":
                self.data["tau_evidence"] = reader.belief.evidence.state()
            self.data["rounds"].setdefault(label, {})[key] = {
                "reaction_time": round(estimate.reaction_time, 4), "decision_time": round(estimate.phi[1], 4),
                "sd": [round(x, 4) for x in estimate.sd], "stepped": estimate.stepped, **response.to_dict(),
                "evidence": len(reader.belief.evidence)}
        out = {}
        for method in methods:
            key = "adapt_driver_prior" if method == "adapt_driver_prior" else "adapt_driver"
            out[method] = self.tracker(method, estimates.get(key) if method != "adapt_driver_static" else None,
                                       response)
        return out

    def meta_update(self, others: list[Evidence], label: str | None = None) -> None:
        """FTML: ``P`` minimizes, over the offline drivers and every online round so far, the loss of the round's
        other drives under ``U(P, tau)``. The ``P`` this round used is kept with its pair (for :meth:`regret`)."""
        tau = self.data.pop("tau_evidence", None)
        if tau is None:
            return
        other = Evidence()
        for e in others:
            other = other + e
        self.data["online_pairs"].append((tau, other.state()))
        self.data.setdefault("online_rounds", []).append({"label": label, "prior": self.data["prior"]})
        pairs = [(Evidence.from_state(a), Evidence.from_state(b))
                 for a, b in [*self.data["offline_pairs"], *self.data["online_pairs"]]]
        seed = len(self.data["online_pairs"])  # each round its own draws, the same in every run
        self.data["prior"] = meta_train(DriverPrior.from_dict(self.data["prior"]), pairs, steps=20, seed=seed).to_dict()

    def regret(self, steps: int = 30) -> dict[str, Any]:
        """The empirical regret of FTML's meta model, as ``adapt``'s (the paper's Eq. 3): per online round ``t``,
        ``l_t(U(P_t, tau_t)) - l_t(U(P_h, tau_t))``, with ``l_t`` the round's other drives' :func:`nll` per item
        under ``U`` on its ``tau`` (:func:`~pernav.learners.driver.meta_loss`) and ``P_h`` the best meta model in
        hindsight over the online rounds: the cheapest over them all of FTML's own ``P_t``'s, its last ``P`` and a
        ``steps``-step fit on every online pair from the ``P`` of the first round. ``P_h`` only approximates the
        minimizer, so the regret is at most what it would be against the exact one. Rounds without other drives'
        evidence to score are left out.

        >>> from pernav.learners.belief import AnswerDetector
        >>> DriverState({"detector": AnswerDetector().state_dict(), "online_pairs": []}).regret()["loss_regret"]
        []
        """
        rounds = self.data.get("online_rounds", [])
        pairs = [(Evidence.from_state(a), Evidence.from_state(b)) for a, b in self.data["online_pairs"][-len(rounds):]
                 ] if rounds else []
        scored = [(r, pair) for r, pair in zip(rounds, pairs, strict=True) if len(pair[1]) > 0]
        if not scored:
            return {"labels": [], "loss_regret": [], "average_loss_regret": [], "hindsight_prior": None}
        online = [pair for _, pair in scored]
        priors = [DriverPrior.from_dict(r["prior"]) for r, _ in scored]
        candidates = [*priors, DriverPrior.from_dict(self.data["prior"]), meta_train(priors[0], online, steps=steps)]
        key = [json.dumps(p.to_dict(), sort_keys=True) for p in candidates]  # FTML often keeps P: each scored once
        each = {k: [meta_loss(p, [pair]) for pair in online] for k, p in zip(key, candidates, strict=True)}
        items = [len(other) for _, other in online]

        def total(k: str) -> float:  # meta_loss over every online pair: per item of evidence
            return sum(loss * n for loss, n in zip(each[k], items, strict=True)) / sum(items)

        best = min(dict.fromkeys(key), key=total)
        losses = [each[k][t] - each[best][t] for t, k in enumerate(key[: len(priors)])]
        return {"labels": [r["label"] for r, _ in scored], "loss_regret": losses,
                "average_loss_regret": running_mean(losses),
                "hindsight_prior": candidates[key.index(best)].to_dict()}

