"""How far can the hybrid driver model's structure go on the model diagnostic, and where does the diagnostic cap it?

``pernav diagnose model`` correlates a model's predicted "prompt now vs 3 s later" divergence with the true
simulator's (a mean over 2 samples) at the panel drivers' approach states. This script takes the same states (the
same episodes, seeds and pairs: it runs ``approach_divergences`` itself) and measures, without any study:

* ``ceiling``: the true simulator's mean over ``--ceiling`` (20) fresh samples against the same 2-sample truth: the
  r a perfect model of the expectation reaches (the acceptance's "ceiling");
* ``prior``: the hybrid model (``DriverImaginedEnv``) with ``DriverParams()``'s defaults;
* ``true_params``: the model given the simulated driver's own reaction and decision time, turn speed, braking and
  acceleration (read from the profile) and the cruise the learner reads from an explore drive
  (:func:`~pernav.learners.driver.read_response`): a check of the model's *structure*, not a learner at round time;
* ``tau_speeds``: the driver's own reaction and decision time, and the speeds ``adapt_driver`` reads from the
  diagnostic's explore drive (``read_response``: cruise, turn speed, braking, acceleration), as at round time, with
  ``--prepared`` the slowing on a "prepare" (adapt_driver's offline phase fits it: 0.85-0.87 on 24 population drivers
  of Town1; the default is the model's own assumption);
* ``tau_prepared``: ``tau_speeds`` with the share of its cruise the driver drives at after a "prepare" read from the
  diagnostic's explore drive as ``adapt_driver`` reads it (:func:`~pernav.learners.driver.read_prepared`, with
  ``--reaction`` the reaction time known before the drive, shrunk toward ``--prepared``);
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

from pernav.diagnostics.model_check import DELAY, STEPS, approach_divergences, driver_env
from pernav.diagnostics.panel import PANEL
from pernav.env.torchrl_env import explore_module
from pernav.learners.driver import read_prepared, read_response
from pernav.model.driver import DriverImaginedEnv, DriverParams
from pernav.trainer.collect import drive
from pernav.world.drivers import Context, DriverProfile, named_user, resolve

K = 10  # the diagnostic's history window for the hybrid model
GRID = {"prepared": (0.6, 0.75, 0.85, 0.95, 1.0), "brake": (0.5, 1.0, 2.0, 3.0, 5.0), "accel": (0.5, 1.5, 3.0, 4.5)}


def true_params(user, context: dict, cruise: float) -> DriverParams:
    """The hybrid model's parameters as the panel driver ``user`` (a name or a profile dict) has them."""
    profile = named_user(user) if isinstance(user, str) else DriverProfile(**user)
    d = resolve(profile, Context(**context))
    return DriverParams(reaction_time=d.reaction_time, decision_time=d.decision_time, turn_speed=d.turn_speed,
                        brake=d.comfort_decel, accel=d.comfort_accel, cruise=cruise)


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
    ap.add_argument("--prepared", type=float, default=DriverParams().prepared,
                    help="the tau_speeds row's share of its speed a driver slows to on a prepare")
    ap.add_argument("--reaction", type=float, default=1.3,
                    help="the tau_prepared row's reaction time for reading the slowing on a prepare from tau (about "
                         "P's centre, as a first drive reads it)")
    ap.add_argument("--no-grid", action="store_true", help="skip best_response (its grid is most of the time)")
    ap.add_argument("--first-episode", type=int, default=0,
                    help="the first of the two panel episodes (0: the diagnostic's own states; 2: held-out ones, other "
                         "routes and seeds, for checking a change found on the diagnostic's states)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    pooled: dict[str, list] = {}
    rows = {}
    for driver, (user, context) in PANEL.items():
        tau = drive(driver_env(driver, args.town, 7, 77, K), explore_module())  # the diagnostic's tau
        seen = read_response(tau)
        cruise = seen.cruise
        own = true_params(user, context, cruise)
        speeds = dataclasses.replace(own, turn_speed=seen.turn_speed, brake=seen.brake, accel=seen.accel,
                                     prepared=args.prepared)
        # every candidate is a model of the diagnostic's own loop: the same states, seeds and truth
        grid = [] if args.no_grid else [dataclasses.replace(own, **dict(zip(GRID, v, strict=True)))
                                        for v in itertools.product(*GRID.values())]
        tau_prepared = dataclasses.replace(speeds, prepared=read_prepared(tau, args.reaction, cruise, args.prepared))
        models = {"prior": DriverParams(), "true_params": own, "tau_speeds": speeds, "tau_prepared": tau_prepared,
                  **{f"grid{i}": p for i, p in enumerate(grid)}}
        div = approach_divergences(driver, args.town, {k: (DriverImaginedEnv([p]), None) for k, p in models.items()},
                                   K=K, ceiling=args.ceiling, first=args.first_episode)
        true = div["true"]
        if not len(true):
            continue
        preds = {"prior": div["prior"], "true_params": div["true_params"], "tau_speeds": div["tau_speeds"],
                 "tau_prepared": div["tau_prepared"],
                 **({"ceiling": div["ceiling"]} if args.ceiling else {})}
        best = None
        if grid:
            errors = [float(((div[f"grid{i}"] - true) ** 2).mean()) for i in range(len(grid))]
            k = int(np.argmin(errors))  # the first of equal errors
            best, preds["best_response"] = grid[k], div[f"grid{k}"]
        pooled.setdefault("true", []).append(true)
        for k, v in preds.items():
            pooled.setdefault(k, []).append(v)
        rows[driver] = {"states": len(true), "true_mean": [round(float(x), 2) for x in true.mean(0)],
                        "cruise": round(cruise, 2),
                        "read_from_tau": {**seen.to_dict(), "prepared": round(tau_prepared.prepared, 3)},
                        **({"best_response_params": {k: getattr(best, k) for k in GRID}} if best else {}),
                        **{k: figures(true, v) for k, v in preds.items()}}
        print(driver, json.dumps(rows[driver]), flush=True)
    cat = {k: np.concatenate(v) for k, v in pooled.items()}
    report = {"town": args.town, "first_episode": args.first_episode, "steps": STEPS, "delay_s": DELAY,
              "ceiling_samples": args.ceiling,
              "states": int(cat["true"].shape[0]), "drivers": rows,
              "pooled": {k: figures(cat["true"], v) for k, v in cat.items() if k != "true"}}
    print(json.dumps(report["pooled"], indent=1))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(report, f, indent=1)


if __name__ == "__main__":
    main()
