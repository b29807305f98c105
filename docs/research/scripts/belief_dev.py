"""The belief learner on development drivers (never the benchmarks'): how well the posterior from 1, 2, 3 and 5
explore drives of a driver reads its log reaction time (held-out R^2), and how often its 90 % interval holds it.

The detector and prior are fitted as the study fits them (pernav.trainer.answers.fit_belief, the study's defaults:
96 drivers, 4 traffic cars) on Population(seed=9103); they read 50 other drivers, Population(seed=9104), each driving
five explore routes (route and world seeds 12-16). About 4 minutes per town on one core.

Run: .venv/bin/python docs/research/scripts/belief_dev.py Town1 [--cache /tmp/belief_dev_Town1.pkl]
"""

import argparse
import math
import pickle
from pathlib import Path

import numpy as np
import torch

from pernav.model.belief import ReactionBelief
from pernav.study.config import BELIEF_DEFAULTS
from pernav.trainer.answers import fit_belief, labelled_drives

TRAIN, TEST, DRIVE_SEEDS = (9103, 11, 96), (9104, 50), (12, 13, 14, 15, 16)


def collect(town: str) -> list:
    config = {"n_traffic": 4}
    train = labelled_drives(town, TRAIN[2], TRAIN[0], TRAIN[1], config)
    return [train] + [labelled_drives(town, TEST[1], TEST[0], s, config) for s in DRIVE_SEEDS]


def evaluate(sets: list, drives: int, detector, prior: ReactionBelief) -> dict:
    truth, mean, inside, sd = [], [], [], []
    for k in range(len(sets[1])):
        belief = ReactionBelief.from_state_dict(prior.state_dict())
        for drive_set in sets[1: 1 + drives]:
            for answer in drive_set[k].answers:
                with torch.no_grad():
                    p = detector(answer.features, answer.prepare).exp()
                belief.update(answer.delays, p[:-1], float(p[-1]))
        R = sets[1][k].reaction_time
        low, high = belief.interval(0.9)
        truth.append(math.log(R))
        mean.append(belief.mean)
        inside.append(low <= R <= high)
        sd.append(belief.sd)
    y, m = np.array(truth), np.array(mean)
    return {"drives": drives, "r2": round(float(1 - ((y - m) ** 2).sum() / ((y - y.mean()) ** 2).sum()), 3),
            "r": round(float(np.corrcoef(y, m)[0, 1]), 3), "coverage_90": round(float(np.mean(inside)), 3),
            "sd_log_R": round(float(np.mean(sd)), 3), "bias_log_R": round(float(np.mean(m - y)), 3), "n": len(y)}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("town")
    parser.add_argument("--cache", help="a pickle of the drives (written if missing)")
    args = parser.parse_args()
    cache = Path(args.cache) if args.cache else None
    if cache is not None and cache.exists():
        sets = pickle.loads(cache.read_bytes())
    else:
        sets = collect(args.town)
        if cache is not None:
            cache.write_bytes(pickle.dumps(sets))
    options = {k: BELIEF_DEFAULTS[k] for k in ("noise", "outlier", "quantile")}
    detector, prior = fit_belief(sets[0], **options)
    for drives in (1, 2, 3, 5):
        print(args.town, evaluate(sets, drives, detector, prior))


if __name__ == "__main__":
    main()
