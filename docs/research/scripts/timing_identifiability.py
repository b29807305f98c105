"""Can one explore drive show a driver's prompt timing? (research check, world v2; docs/personal.md)

Simulated drivers of the population prior each drive one explore route. For each drive this prints the driver's
effective reaction and decision times, explore's share of late "turn" prompts and its excess over the oracle's
(:func:`pernav.env.policies.lateness`, from the profile), and what the navigation sees: the 12
:func:`pernav.learners.timing.timing_features` and the delay (steps) from each "prepare" prompt said at speed to the
first step in which the car slows. It then reports each feature's AUC for the late class (excess >= 0.05) and the
leave-one-out R^2 of ridge regressions of log reaction time, log decision time, the excess and the oracle's "turn"
lead (s at 10 m/s). With ``--tau-policy retimed`` the drive is explore re-timed at random on every prompt it can move
(:class:`pernav.planner.retiming.RetimedExplore`, p = 1), and three more features describe the "turn" prompts'
outcomes against their lead (s to the junction when said): the share missed among prompts said under 4 s, the
share missed or answered by hard braking or steering, and the shortest lead of a prompt answered calmly.

Run (about 4 min for 80 drivers in Town3, 7 min in Town1, one core):
    .venv/bin/python docs/research/scripts/timing_identifiability.py Town3 80 778 [--tau-policy retimed]
"""

from __future__ import annotations

import argparse
import random

import numpy as np

from pernav.env.policies import lateness, oracle_policy
from pernav.env.torchrl_env import explore_module
from pernav.learners.timing import FEATURES, timing_features
from pernav.planner.retiming import RetimedExplore
from pernav.study import episodes
from pernav.study.config import preset
from pernav.study.schedule import Entry
from pernav.world.drivers import Population, resolve


def prepare_delay(trajectory) -> float:
    """Mean steps from a "prepare" prompt said above 4 m/s to the first step with the brake on or 0.3 m/s lost."""
    a = trajectory["action"].reshape(-1).tolist()
    speed = trajectory["next", "observation"].float()[:, [3, 4]].norm(dim=-1)
    before = trajectory["observation"].float()[:, [3, 4]].norm(dim=-1)
    brake = trajectory["next", "observation"].float()[:, 13]
    delays = []
    for t in range(len(a)):
        if a[t] in (3, 4) and (t == 0 or a[t - 1] != a[t]) and before[t] > 4:
            j = next((j for j in range(t, min(t + 8, len(a))) if brake[j] > 0.02 or speed[j] < before[j] - 0.3), None)
            delays.append(8 if j is None else j - t)
    return float(np.mean(delays)) if delays else float("nan")


def turn_outcomes(trajectory) -> list[float]:
    """Outcomes of the "turn" prompts against their lead: share missed under 4 s, share missed or answered hard,
    shortest lead answered calmly (20 s if none)."""
    a = trajectory["action"].reshape(-1).tolist()
    speed = trajectory["observation"].float()[:, [3, 4]].norm(dim=-1).clamp(min=3.0)
    to_junction = trajectory["distance_to_junction"].float().reshape(-1)
    missed = (trajectory["next", "missed_turns"] + trajectory["next", "wrong_turns"]).reshape(-1).float()
    after = trajectory["next", "observation"].float()
    turns = [t for t in range(len(a)) if a[t] in (1, 2) and (t == 0 or a[t - 1] not in (1, 2))]
    prompts = []
    for i, t in enumerate(turns):
        end = min(turns[i + 1] if i + 1 < len(turns) else len(a), t + 15)
        lead = float(to_junction[t] / speed[t])
        if lead <= 20:
            miss = float(missed[end - 1] - (missed[t - 1] if t > 0 else 0.0)) > 0
            hard = float(after[t:end, 13].max()) > 0.5 or float(after[t:end, 11].abs().max()) > 0.8
            prompts.append((lead, miss, miss or hard))
    short = [m for lead, m, _ in prompts if lead < 4]
    calm = [lead for lead, _, bad in prompts if not bad]
    return [float(np.mean(short)) if short else float("nan"),
            float(np.mean([b for *_, b in prompts])) if prompts else float("nan"), min(calm, default=20.0)]


def auc(score: np.ndarray, label: np.ndarray) -> float:
    pos, neg = score[label], score[~label]
    return float((pos[:, None] > neg[None]).mean() + 0.5 * (pos[:, None] == neg[None]).mean())


def loo_r2(X: np.ndarray, y: np.ndarray, l2: float = 10.0) -> float:
    pred = np.zeros(len(y))
    for i in range(len(y)):
        m = np.arange(len(y)) != i
        mu, sd = X[m].mean(0), X[m].std(0) + 1e-9
        A = np.c_[np.ones(m.sum()), (X[m] - mu) / sd]
        P = np.eye(A.shape[1]) * l2
        P[0, 0] = 0.0
        w = np.linalg.solve(A.T @ A + P, A.T @ y[m])
        pred[i] = np.r_[1.0, (X[i] - mu) / sd] @ w
    return float(1 - ((pred - y) ** 2).sum() / ((y - y.mean()) ** 2).sum())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("town")
    ap.add_argument("drivers", type=int)
    ap.add_argument("population_seed", type=int)
    ap.add_argument("--tau-policy", dest="tau_policy", choices=("explore", "retimed"), default="explore")
    args = ap.parse_args()
    cfg, population, rng = preset("personal"), Population(seed=args.population_seed), random.Random(args.population_seed)
    rows = []
    for k in range(args.drivers):
        profile, context = population.sample()
        entry = Entry(f"p{k}", "offline", profile.to_dict(), **context.to_dict())
        policy = explore_module() if args.tau_policy == "explore" else RetimedExplore(p=1.0, seed=5000 + k)
        tau = episodes.episode(cfg, args.town, entry, rng.randrange(10), 1000 + k, policy)
        d = resolve(profile, context)
        late = lateness(d)
        outcomes = turn_outcomes(tau) if args.tau_policy == "retimed" else []
        rows.append([d.reaction_time, d.decision_time, late["explore"], late["excess"],
                     oracle_policy(d).turn_lead(10.0) / 10.0, *outcomes, prepare_delay(tau),
                     *timing_features(tau).tolist()])
    R = np.array(rows)
    for j in range(R.shape[1]):  # a drive without such prompts: the mean of the others
        R[np.isnan(R[:, j]), j] = np.nanmean(R[:, j])
    n_extra = 1 + (3 if args.tau_policy == "retimed" else 0)  # prepare delay (+ the turn outcomes)
    extra_names = ["missed under 4 s", "missed or hard", "shortest calm lead"][:n_extra - 1] + ["prepare delay"]
    late = R[:, 3] >= 0.05
    corr = [np.corrcoef(R[:, 3], R[:, i])[0, 1] for i in (0, 1)]
    print(f"{args.town}: {len(R)} drivers, {late.mean():.0%} late; corr excess~RT {corr[0]:.2f}, ~DT {corr[1]:.2f}")
    names = [*extra_names, *FEATURES]
    for i, name in enumerate(names):
        print(f"  {name:38s} AUC late {auc(R[:, 5 + i], late):.2f}")
    for name, X in (("12 features", R[:, 5 + n_extra:]), (f"12 features + {', '.join(extra_names)}", R[:, 5:])):
        r2 = [loo_r2(X, y) for y in (np.log(R[:, 0]), np.log(R[:, 1]), R[:, 3], R[:, 4])]
        print(f"  {name}: LOO R^2 log RT {r2[0]:+.2f}, log DT {r2[1]:+.2f}, excess {r2[2]:+.2f}, oracle lead {r2[3]:+.2f}")


if __name__ == "__main__":
    main()
