"""The belief learner on development drivers (never the benchmarks'): how well the posterior from 1, 2, 3 and 5
explore drives of a driver reads its log reaction time (held-out R^2), how often its 90 % interval holds it and, with
``--decision``, the same for the decision time.

The detector, prior (and with ``--decision`` the swerve detector and the decision time's likelihood) are fitted as
the study fits them (pernav.learners.answers.fit_belief, the study's defaults: 96 drivers, 4 traffic cars) on
Population(seed=TRAIN); they read 50 other drivers, Population(seed=TEST), each driving five explore routes (route and
world seeds 12-16). About 4 minutes per town on one core.

Development seeds: 9101/9102 chose the likelihood's form, 9103/9104 confirmed it (docs/personal.md); 9105/9106 are
for developing the decision time and the interval's calibration, 9107/9108 confirm them once; 9109/9110 (Town3, 200
drivers, three drives) measure the three-drive R^2 once more, sized (docs/personal.md).

Run: .venv/bin/python docs/research/scripts/belief_dev.py Town1 [--train 9103 --test 9104] [--decision 0|1]
     [--option noise=0.15 ...] [--cache /tmp/belief_dev_Town1.pkl] [--drivers 50 --drives 5 --boot 4000]
"""

import argparse
import math
import pickle
from pathlib import Path

import numpy as np
import torch

from pernav.learners.answers import drive_outcomes, fit_belief, labelled_drives
from pernav.learners.belief import ReactionBelief
from pernav.study.config import BELIEF_DEFAULTS

ROUTE_SEED, N_TRAIN, N_TEST, DRIVE_SEEDS = 11, 96, 50, (12, 13, 14, 15, 16)


def collect(town: str, train: int, test: int, n_test: int = N_TEST, drives: int = len(DRIVE_SEEDS)) -> list:
    config = {"n_traffic": 4}
    fit = labelled_drives(town, N_TRAIN, train, ROUTE_SEED, config, progress=True)
    return [fit] + [labelled_drives(town, n_test, test, s, config, progress=True) for s in DRIVE_SEEDS[:drives]]


def _r2(y: np.ndarray, m: np.ndarray) -> float:
    return round(float(1 - ((y - m) ** 2).sum() / ((y - y.mean()) ** 2).sum()), 3)


def evaluate(sets: list, drives: int, detector, prior: ReactionBelief, swerve, boot: int = 0) -> dict:
    truth, mean, inside, sd, d_truth, d_mean, d_inside, d_sd, acted = [], [], [], [], [], [], [], [], []
    for k in range(len(sets[1])):
        belief = ReactionBelief.from_state_dict(prior.state_dict())
        for drive_set in sets[1: 1 + drives]:
            drive = drive_set[k]
            for answer in drive.answers:
                with torch.no_grad():
                    p = detector(answer.features, answer.prepare).exp()
                belief.update(answer.delays, p[:-1], float(p[-1]))
            if swerve is not None:
                for outcome in drive_outcomes(drive, swerve):
                    belief.update_turn(outcome.room, outcome.late)
        R, D = sets[1][k].reaction_time, sets[1][k].decision_time
        low, high = belief.interval(0.9)
        truth.append(math.log(R))
        mean.append(belief.mean)
        inside.append(low <= R <= high)
        sd.append(belief.sd)
        if swerve is not None:
            low, high = belief.decision_interval(0.9)
            d_truth.append(D)
            d_mean.append(belief.decision_mean)
            d_inside.append(low - 0.05 <= D <= high + 0.05)  # the grid's step is 0.1 s
            d_sd.append(belief.decision_sd)
            acted.append(belief.belief().get("decision_time", 0.0) > 0)
    y, m = np.array(truth), np.array(mean)
    out = {"drives": drives, "r2": _r2(y, m), "r": round(float(np.corrcoef(y, m)[0, 1]), 3),
           "coverage_90": round(float(np.mean(inside)), 3), "sd_log_R": round(float(np.mean(sd)), 3),
           "bias_log_R": round(float(np.mean(m - y)), 3), "n": len(y)}
    if boot:  # resample the drivers: R^2's 95 % CI
        rng = np.random.default_rng(0)
        draws = [_r2(y[i], m[i]) for i in (rng.integers(0, len(y), len(y)) for _ in range(boot))]
        out["r2_ci95"] = [round(float(v), 3) for v in np.percentile(draws, [2.5, 97.5])]
    if swerve is not None:
        y, m = np.array(d_truth), np.array(d_mean)
        out.update({"D_r2": _r2(y, m), "D_r": round(float(np.corrcoef(y, m)[0, 1]), 3),
                    "D_coverage_90": round(float(np.mean(d_inside)), 3), "D_sd": round(float(np.mean(d_sd)), 3),
                    "D_prior_sd": round(float(prior.decision.sd), 3), "D_bias": round(float(np.mean(m - y)), 3),
                    "D_acted_on": int(np.sum(acted))})
    return out


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("town")
    parser.add_argument("--train", type=int, default=9103)
    parser.add_argument("--test", type=int, default=9104)
    parser.add_argument("--decision", type=int, default=BELIEF_DEFAULTS["decision"], help="1: the decision time too")
    parser.add_argument("--option", action="append", default=[], help="KEY=VALUE of the belief's options")
    parser.add_argument("--cache", help="a pickle of the drives (written if missing)")
    parser.add_argument("--drivers", type=int, default=N_TEST, help="drivers read (Population(seed=TEST))")
    parser.add_argument("--drives", type=int, default=len(DRIVE_SEEDS), help="drives read per driver (1-5)")
    parser.add_argument("--boot", type=int, default=0, help="bootstrap resamples of the drivers for R^2's 95 %% CI")
    args = parser.parse_args()
    cache = Path(args.cache) if args.cache else None
    if cache is not None and cache.exists():
        sets = pickle.loads(cache.read_bytes())
    else:
        sets = collect(args.town, args.train, args.test, args.drivers, args.drives)
        if cache is not None:
            cache.write_bytes(pickle.dumps(sets))
    options = {k: BELIEF_DEFAULTS[k] for k in ("noise", "outlier", "quantile", "drift")}
    options.update({k: float(v) for k, v in (o.split("=") for o in args.option)})
    detector, prior, swerve = fit_belief(sets[0], decision=bool(args.decision), **options)
    if swerve is not None:
        print(args.town, "decision prior", prior.decision)
    for drives in (d for d in (1, 2, 3, 5) if d < len(sets)):
        print(args.town, evaluate(sets, drives, detector, prior, swerve, args.boot), flush=True)


if __name__ == "__main__":
    main()
