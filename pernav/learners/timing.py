"""A driver's prompt timing read from one drive: features of the adaptation trajectory tau and a model, trained
offline on simulated drivers, that maps them to the timing parameters the prompt rules read.

The paper's dynamics model adapts to tau by one gradient step of a loss over the whole state, which is dominated
by where the car goes in traffic; one explore drive shows no variation of a prompt's timing, so the step learns
nothing about *when* this driver acts on a prompt. This model reads what a navigation system sees of that in tau:
turns missed and re-routes after its "turn" prompts, the braking and steering of the approach, how far before the
junction the car began to slow, the tracking error and the cruising speed. It is fitted offline on the drives of
simulated drivers of the population prior, whose effective reaction and decision times are known (the paper's
offline MDPs), by ridge regression in log space; at round time it sees tau only. Its output is a *belief* about
the user (:func:`pernav.env.policies.belief_policy`: explore's rule re-timed for it). The predicted *mean* decides
whether to leave explore at all: only when it moves the "turn" prompt earlier by at least ``gate`` seconds (a
driver the evidence places inside explore's slack keeps explore's timing). The belief then acted on is raised
``quantile`` residual SDs above that mean: a late prompt costs far more than an early one. With ``guard`` the belief
also names the quickest driver the evidence allows, so that the re-timed rule never says a prompt so early that
such a driver acts on it at the junction before the one meant (a roundabout exit to pass), and the rule, unsure of
its user, says a turn or "prepare" only once the car is inside the last junction box before the one meant (a
prompt heard before a box is taken for that junction and dropped): the early prompts are for the slow driver the
belief fears, not a trap for the quick one it may be.

Example:
    >>> import torch
    >>> X = torch.randn(64, N_FEATURES, generator=torch.Generator().manual_seed(0))
    >>> Y = torch.stack([1.2 + 0.3 * X[:, 0], 2.0 + 0.2 * X[:, 1]], -1).clamp(min=0.5)
    >>> model = TimingModel().fit(X, Y)
    >>> model.predict(X[:2]).shape
    torch.Size([2, 2])
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import torch
from tensordict import TensorDictBase

from pernav.env.layout import STATE_KEYS
from pernav.env.policies import belief_policy, explore_policy
from pernav.world.constants import TURNS

__all__ = ["FEATURES", "N_FEATURES", "TARGETS", "TimingModel", "timing_features"]

#: what the features are, in order
FEATURES = ("missed per turn prompt", "re-routes per turn prompt", "kerb strikes per turn prompt",
            "collisions per turn prompt", "hard braking per approach", "mean peak braking", "mean peak steering",
            "log tracking cost per step", "cruising speed (m/s)", "time to junction at braking onset (s)",
            "braking share of steps", "turn prompts")
N_FEATURES = len(FEATURES)
#: the effective driver fields the model predicts (the rules' timing inputs)
TARGETS = ("reaction_time", "decision_time")
_SPEED = (STATE_KEYS.index("vx"), STATE_KEYS.index("vy"))  # observation entries (pernav.env.layout)
_BRAKE, _STEER = STATE_KEYS.index("brake"), STATE_KEYS.index("steering")


def timing_features(trajectory: TensorDictBase) -> torch.Tensor:
    """``[N_FEATURES]`` features of one drive ``[T]`` (a tau): only what the navigation saw (its prompts, the car's
    state, its route events), never the driver's profile or the oracle's actions.

    >>> from pernav.trainer.collect import drive, history_env
    >>> from pernav.env.torchrl_env import explore_module
    >>> tau = drive(history_env("Town1", {"route": 0}, config={"n_traffic": 2}, seed=0), explore_module())
    >>> timing_features(tau).shape
    torch.Size([12])
    """
    a = trajectory["action"].reshape(-1).tolist()
    obs = trajectory["observation"].float()
    speed = obs[:, list(_SPEED)].norm(dim=-1)
    brake, steer = obs[:, _BRAKE], obs[:, _STEER].abs()
    to_junction = trajectory["distance_to_junction"].float().reshape(-1)
    last = trajectory[-1]["next"]
    T = len(a)
    turns = [t for t in range(T) if a[t] in TURNS and (t == 0 or a[t - 1] != a[t])]
    n = max(len(turns), 1)
    peak_brake, peak_steer, onset = [], [], []
    for t in turns:
        end = t  # the approach: from the prompt until the junction is passed (the distance stops falling)
        while end + 1 < T and to_junction[end + 1] <= to_junction[end] + 1.0 and end - t < 15:
            end += 1
        window = slice(t, min(end + 2, T))
        peak_brake.append(float(brake[window].max()))
        peak_steer.append(float(steer[window].max()))
        first = next((k for k in range(t, min(end + 2, T)) if brake[k] > 0.05), None)
        onset.append(float(to_junction[first] / speed[first].clamp(min=1.0)) if first is not None else 0.0)

    def mean(x: list[float]) -> float:
        return sum(x) / len(x) if x else 0.0

    events = [float(last[k]) for k in ("missed_turns", "reroutes", "edge_strikes", "collisions")]
    events[0] += float(last["wrong_turns"])
    return torch.tensor([*(e / n for e in events), mean([float(b > 0.5) for b in peak_brake]), mean(peak_brake),
                         mean(peak_steer), math.log(float(last["tracking_cost"]) / T + 1e-3),
                         float(torch.quantile(speed, 0.9)), mean(onset), float((brake > 0).float().mean()),
                         float(len(turns))])


class TimingModel:
    """Ridge regression from :func:`timing_features` to the log of the :data:`TARGETS`, with the belief it gives.

    Args:
        l2: ridge penalty on the standardized features.
        quantile: residual SDs above the predicted mean that the belief takes (0: the posterior mean).
        gate: seconds by which the belief must move the "turn" prompt earlier than explore's, else explore.
        guard: also name the quickest driver it may be (:meth:`fastest`), so that the re-timed rule never says a
            prompt so early that a quick driver acts on it at the junction before the one meant.
    """

    def __init__(self, l2: float = 3.0, quantile: float = 1.5, gate: float = 0.0, guard: bool = True) -> None:
        self.l2, self.quantile, self.gate, self.guard = float(l2), float(quantile), float(gate), bool(guard)
        self.mean = self.scale = self.weight = self.resid = None

    def fit(self, features: torch.Tensor, targets: torch.Tensor) -> TimingModel:
        """Fit on ``[N, N_FEATURES]`` features and ``[N, len(TARGETS)]`` effective values of simulated drivers."""
        X, Y = features.double(), targets.double().log()
        if X.shape[0] < 2 or X.shape[0] != Y.shape[0]:
            raise ValueError(f"need >= 2 drives with one target row each; got {X.shape[0]} and {Y.shape[0]}")
        self.mean, self.scale = X.mean(0), X.std(0).clamp(min=1e-6)
        A = torch.cat([torch.ones(len(X), 1, dtype=X.dtype), (X - self.mean) / self.scale], 1)
        penalty = torch.eye(A.shape[1], dtype=X.dtype) * self.l2
        penalty[0, 0] = 0.0  # the intercept is not shrunk: no evidence gives the population's mean
        self.weight = torch.linalg.solve(A.T @ A + penalty, A.T @ Y)
        self.resid = (Y - A @ self.weight).std(0)
        return self

    def predict(self, features: torch.Tensor, quantile: float = 0.0) -> torch.Tensor:
        """``[..., len(TARGETS)]`` effective values: the fitted log mean plus ``quantile`` residual SDs."""
        if self.weight is None:
            raise RuntimeError("fit the TimingModel (or load_state_dict) before predicting")
        X = (features.double() - self.mean) / self.scale
        A = torch.cat([torch.ones(*X.shape[:-1], 1, dtype=X.dtype), X], -1)
        return (A @ self.weight + quantile * self.resid).exp().float()

    def earlier(self, features: torch.Tensor, quantile: float = 0.0) -> float:
        """Seconds by which the belief at ``quantile`` moves the "turn" prompt (at 10 m/s) before explore's."""
        belief = dict(zip(TARGETS, self.predict(features, quantile).tolist(), strict=True))
        return (belief_policy(belief).turn_lead(10.0) - explore_policy().turn_lead(10.0)) / 10.0

    def belief(self, tau: TensorDictBase) -> dict[str, float]:
        """What to believe of the driver of ``tau`` (:func:`pernav.env.policies.belief_policy`): ``{}`` (explore's
        timing) unless the predicted mean moves the "turn" prompt at least ``gate`` seconds earlier; then the
        prediction ``quantile`` residual SDs above the mean."""
        features = timing_features(tau)
        if self.earlier(features) < self.gate:
            return {}
        values = self.predict(features, self.quantile).tolist()
        belief: dict[str, Any] = {name: round(v, 4) for name, v in zip(TARGETS, values, strict=True)}
        if self.guard:
            belief["fastest"] = self.fastest(features)
        return belief

    def fastest(self, features: torch.Tensor) -> dict[str, float]:
        """The quickest driver the evidence allows, for the rules' guards against a too-early prompt: the prediction
        ``quantile`` residual SDs *below* the mean, never slower than the average driver, and its reaction time at
        the 5th percentile of one prompt's draw (a single prompt is heard as quickly as that one time in twenty).

        >>> model = TimingModel().fit(torch.randn(8, N_FEATURES), torch.rand(8, 2) + 1.0)
        >>> model.fastest(torch.zeros(N_FEATURES))["reaction_time"] < explore_policy().driver.reaction_time
        True
        """
        low = dict(zip(TARGETS, self.predict(features, -self.quantile).tolist(), strict=True))
        average = explore_policy().driver
        quick = dataclasses.replace(average, reaction_time=min(low["reaction_time"], average.reaction_time))
        return {"reaction_time": round(quick.reaction_draw(-1.645), 4),
                "decision_time": round(min(low["decision_time"], average.decision_time), 4)}

    def state_dict(self) -> dict[str, Any]:
        return {"l2": self.l2, "quantile": self.quantile, "gate": self.gate, "guard": self.guard,
                "mean": self.mean, "scale": self.scale,
                "weight": self.weight, "resid": self.resid}

    def load_state_dict(self, state: dict[str, Any]) -> TimingModel:
        state = {"guard": False, **state}  # a model saved before the guard existed ran without it
        for key, value in state.items():
            setattr(self, key, value)
        return self
