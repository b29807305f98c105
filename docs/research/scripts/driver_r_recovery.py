"""How well does ``adapt_driver``'s ``U`` read a driver's reaction time from one explore drive, on fresh population
drivers (not the model diagnostic's panel)? ``U(P, tau)``'s ``log R`` against the simulated driver's own, for the
meta model ``P`` of a finished study, the population's statistics ``P0``, and ``P`` with ``P0``'s spread (a check of
FTML's spread, which sets how far ``U`` moves from the centre).

    .venv/bin/python docs/research/scripts/driver_r_recovery.py --study runs/driver --town Town1 --drivers 24
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
import torch

from pernav.learners.answers import labelled_drives
from pernav.learners.belief import detectors
from pernav.learners.driver import DriverPrior, adapt_phi
from pernav.study.driver_rounds import labelled_evidence
from pernav.study.finished import FinishedStudy


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--study", required=True, help="a finished study that ran adapt_driver")
    ap.add_argument("--town", default="Town1")
    ap.add_argument("--drivers", type=int, default=24)
    ap.add_argument("--population-seed", type=int, default=7777, help="not a seed any study or benchmark draws")
    ap.add_argument("--seed", type=int, default=8888)
    args = ap.parse_args()
    torch.set_num_threads(1)
    state = FinishedStudy.open(args.study).driver_state(args.town)
    P, P0 = DriverPrior.from_dict(state.data["prior"]), DriverPrior.from_dict(state.data["prior0"])
    print(f"P: centre {P.mean}, spread {P.sd}; P0: centre {P0.mean}, spread {P0.sd}")
    drives = labelled_drives(args.town, args.drivers, population_seed=args.population_seed, seed=args.seed)
    detector, swerve = detectors(state.data)
    evidence = [labelled_evidence(d, P, detector, swerve) for d in drives]  # what U reads, as a round reads tau
    true = np.log([d.reaction_time for d in drives])
    for name, prior in {"P": P, "P0": P0, "P with P0's spread": dataclasses.replace(P, sd=(P0.sd[0], P.sd[1]))}.items():
        est = np.array([adapt_phi(prior, e).phi[0] for e in evidence])
        print(f"{name:18s} r {np.corrcoef(true, est)[0, 1]:.3f}  slope {np.polyfit(true, est, 1)[0]:.2f}  "
              f"mean |error| {np.abs(est - true).mean():.3f} (log s)")


if __name__ == "__main__":
    main()
