"""How far can the hybrid driver model's structure go on the model diagnostic, and where does the diagnostic cap it?

``pernav diagnose model`` correlates a model's predicted "prompt now vs 3 s later" divergence with the true
simulator's (a mean over 2 samples) at the panel drivers' approach states. This script takes the same states (the
same episodes, seeds and pairs as ``approach_divergences``) and measures, without any study:

* ``ceiling``: the true simulator's mean over ``--ceiling`` (20) fresh samples against the same 2-sample truth: the
  r a perfect model of the expectation reaches (the acceptance's "ceiling");
* ``prior``: the hybrid model (``DriverImaginedEnv``) with ``DriverParams()``'s defaults;
* ``true_params``: the model given the simulated driver's own reaction and decision time, turn speed, braking and
  acceleration (read from the profile) and the cruise the learner reads from an explore drive (``_cruise``): a check
  of the model's *structure*, not a learner at round time;
* ``best_response``: ``true_params`` with each driver's response to a prompt (the share of its cruise it slows to on a
  "prepare", its braking and its acceleration) chosen on a grid to fit *that driver's own diagnostic states* (the
  least squared error of the divergences). It reads the judge's truth, so it is an upper bound on what adapting those
  three numbers per driver could give in this structure, not a result.

    .venv/bin/python docs/research/scripts/driver_model_ceiling.py --town Town1 --json out.json
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json

import numpy as np
import torch

from pernav.diagnostics import TrueDynamicsEnv
from pernav.diagnostics.model_check import DELAY, STEPS, approach_pairs, driver_env
from pernav.diagnostics.panel import PANEL
from pernav.env.torchrl_env import explore_module
from pernav.model.driver import DriverImaginedEnv, DriverParams
from pernav.study.driver_rounds import _cruise
from pernav.trainer.collect import drive
from pernav.world.drivers import Context, DriverProfile, named_user, resolve

K = 10  # the diagnostic's history window for the hybrid model
GRID = {"prepared": (0.6, 0.75, 0.85, 0.95, 1.0), "brake": (0.5, 1.0, 2.0, 3.0, 5.0), "accel": (0.5, 1.5, 3.0, 4.5)}
IDX = [s - 1 for s in STEPS]


def true_params(user, context: dict, cruise: float) -> DriverParams:
    """The hybrid model's parameters as the panel driver ``user`` (a name or a profile dict) has them."""
    profile = named_user(user) if isinstance(user, str) else DriverProfile(**user)
    d = resolve(profile, Context(**context))
    return DriverParams(reaction_time=d.reaction_time, decision_time=d.decision_time, turn_speed=d.turn_speed,
                        brake=d.comfort_decel, accel=d.comfort_accel, cruise=cruise)


def approach_states(driver: str, town: str, ceiling: int) -> list[dict]:
    """The diagnostic's approach states of ``driver`` (:func:`approach_pairs`): each root, its pair of sequences, the
    2-sample true divergence (as the diagnostic measures it) and (``ceiling`` > 0) the many-sample one."""
    states = []
    for td, nav, t, pair in approach_pairs(driver, town, K=K):
        pos, _ = TrueDynamicsEnv(nav, samples=2, seed=t).imagine(td, pair)
        row = {"root": td.select("history", "route_ahead", "distance_to_junction").clone(), "pair": pair,
               "true": (pos[:, 0] - pos[:, 1]).norm(dim=-1).mean(0)[IDX].numpy()}
        if ceiling:
            p, _ = TrueDynamicsEnv(nav, samples=ceiling, seed=10_000 + t).imagine(td, pair)
            row["ceiling"] = (p[:, 0] - p[:, 1]).norm(dim=-1).mean(0)[IDX].numpy()
        states.append(row)
    return states


def predicted(params: DriverParams, states: list[dict]) -> np.ndarray:
    """``[n, len(STEPS)]``: the hybrid model's divergence at each state (its rows' mean, as the diagnostic takes)."""
    env = DriverImaginedEnv([params])
    out = []
    for s in states:
        p, _ = env.imagine(s["root"], s["pair"])
        out.append((p[:, 0] - p[:, 1]).norm(dim=-1).mean(0)[IDX].numpy())
    return np.array(out)


def figures(true: np.ndarray, pred: np.ndarray) -> dict:
    """Pearson r per horizon and the share of states where the truth is under 0.5 m and the prediction under 1 m."""
    with np.errstate(invalid="ignore", divide="ignore"):
        r = [float(np.corrcoef(true[:, i], pred[:, i])[0, 1]) for i in range(len(STEPS))]
    small = true < 0.5
    quiet = [float((pred[:, i][small[:, i]] < 1.0).mean()) if small[:, i].any() else None for i in range(len(STEPS))]
    return {"r": [None if np.isnan(x) else round(x, 3) for x in r],
            "under_1m_where_true_under_0_5m": [None if q is None else round(q, 3) for q in quiet],
            "mean": [round(float(x), 2) for x in pred.mean(0)]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--town", default="Town1")
    ap.add_argument("--ceiling", type=int, default=20, help="samples of the ceiling (0: not measured)")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    torch.set_num_threads(1)
    pooled: dict[str, list] = {}
    rows = {}
    for driver, (user, context) in PANEL.items():
        cruise = _cruise(drive(driver_env(driver, args.town, 7, 77, K), explore_module()))  # the diagnostic's tau
        states = approach_states(driver, args.town, args.ceiling)
        if not states:
            continue
        true = np.array([s["true"] for s in states])
        own = true_params(user, context, cruise)
        preds = {"prior": predicted(DriverParams(), states), "true_params": predicted(own, states)}
        if args.ceiling:
            preds["ceiling"] = np.array([s["ceiling"] for s in states])
        best, best_err = None, np.inf
        for values in itertools.product(*GRID.values()):
            params = dataclasses.replace(own, **dict(zip(GRID, values, strict=True)))
            err = float(((predicted(params, states) - true) ** 2).mean())
            if err < best_err:
                best, best_err = params, err
        preds["best_response"] = predicted(best, states)
        pooled.setdefault("true", []).append(true)
        for k, v in preds.items():
            pooled.setdefault(k, []).append(v)
        rows[driver] = {"states": len(states), "true_mean": [round(float(x), 2) for x in true.mean(0)],
                        "cruise": round(cruise, 2),
                        "best_response_params": {k: getattr(best, k) for k in GRID},
                        **{k: figures(true, v) for k, v in preds.items()}}
        print(driver, json.dumps(rows[driver]), flush=True)
    cat = {k: np.concatenate(v) for k, v in pooled.items()}
    report = {"town": args.town, "steps": STEPS, "delay_s": DELAY, "ceiling_samples": args.ceiling,
              "states": int(cat["true"].shape[0]), "drivers": rows,
              "pooled": {k: figures(cat["true"], v) for k, v in cat.items() if k != "true"}}
    print(json.dumps(report["pooled"], indent=1))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(report, f, indent=1)


if __name__ == "__main__":
    main()
