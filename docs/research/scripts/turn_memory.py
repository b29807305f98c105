"""How is an early "turn" lost, as the navigation senses it? Data for ``adapt_driver``'s model, which imagined a "turn"
in effect from its effect until the junction however early it came (docs/adapt_driver.md, "Still blind: an early
turn").

Simulated population drivers (offline, their reaction and decision times known, as ``P0`` reads them) drive explore's
rule said ``shift`` steps early (explore's plan ahead, ``best_shift``'s family), or explore with each "turn" said as
soon as it is ``lead`` steps ahead in explore's plan and not again (:class:`~pernav.learners.answers.EarlyTurn`: what
``adapt_driver``'s planner does). Each announced junction's outcome is read as a round reads it
(:func:`~pernav.learners.answers.drive_outcomes`: the navigation's missed-turn count and the swerve detector, fitted on
explore drives of other drivers): the room from the first "turn"'s audio end to the driver's commit at its decision
time, and whether a swerve or a miss followed. Printed: the late share by cell and by the time the "turn" was held
before the commit (room minus the mean reaction time), beside what the reaction-only likelihood (``false + (hit -
false) P(delay > room)``) predicts and what it predicts with the memory that :func:`fit_memory` fits on all of them
(a "turn" held longer than a lognormal time before the commit is lost).

    .venv/bin/python docs/research/scripts/turn_memory.py --towns Town1 Town5 --drivers 24
"""

from __future__ import annotations

import argparse
import json
import math

import numpy as np
import torch

from pernav.learners.answers import EarlyTurn, fit_decision, labelled_drives, late_probability_each, outcome_rows

HELD_BINS = (-math.inf, 0.0, 2.0, 4.0, 6.0, 8.0, 10.0, math.inf)
#: the memory medians (s) and log-SDs :func:`fit_memory` weighs (and none: a "turn" is never lost)
MEMORY_MEDIANS = tuple(float(m) for m in np.arange(3.0, 30.5, 0.5))
MEMORY_LOG_SDS = (0.1, 0.2, 0.3, 0.5, 0.75, 1.0)


def memory_probability(held: torch.Tensor, median: float, log_sd: float) -> torch.Tensor:
    """The probability that a "turn" in effect ``held`` s before the driver commits is lost by then: the driver keeps it
    in mind a lognormal time (``median``, ``log_sd``; an infinite median: never lost).

    >>> [round(float(p), 2) for p in memory_probability(torch.tensor([-1.0, 5.0, 10.0]), 10.0, 0.3)]
    [0.0, 0.01, 0.5]
    """
    held = torch.as_tensor(held, dtype=torch.float64)
    if not math.isfinite(median):
        return torch.zeros_like(held)
    z = (held.clamp(min=1e-3).log() - math.log(median)) / log_sd
    return torch.where(held > 0, 0.5 * torch.erfc(-z / math.sqrt(2)), torch.zeros_like(z))


def fit_memory(room: torch.Tensor, late: torch.Tensor, R: torch.Tensor, hit: float, false: float
               ) -> tuple[float, float, float]:
    """``(median, log_sd, gain)``: how long a driver keeps a "turn" in mind before it commits, by maximum likelihood
    on announced junctions' outcomes (``outcome_rows`` of early-turn drives: ``room`` at the driver's own decision
    time, ``late``, the driver's true mean reaction ``R``): an outcome is late if the prompt came after the commit or
    was held longer than the memory (:func:`memory_probability`, at the time from its mean effect to the commit), and
    shows with ``hit`` or ``false`` (``fit_decision``'s). ``gain``: the log likelihood over no memory (median
    ``inf``, which it returns where no memory is more likely).

    >>> room = torch.tensor([3.0, 6.0, 14.0, 15.0] * 20, dtype=torch.float64)
    >>> late = torch.tensor([False, False, True, True] * 20)
    >>> median, log_sd, gain = fit_memory(room, late, torch.ones(80, dtype=torch.float64), 0.9, 0.01)
    >>> 5.0 < median < 13.0 and gain > 0
    True
    """
    p_react, held = late_probability_each(R, room), room - R

    def loglik(p: torch.Tensor) -> float:
        p = false + (hit - false) * p
        return float(torch.where(late, p, 1 - p).clamp(min=1e-300).log().sum())

    base = loglik(p_react)
    best = (base, math.inf, 0.0)
    for median in MEMORY_MEDIANS:
        for log_sd in MEMORY_LOG_SDS:
            ll = loglik(p_react + (1 - p_react) * memory_probability(held, median, log_sd))
            if ll > best[0]:
                best = (ll, median, log_sd)
    return best[1], best[2], best[0] - base


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--towns", nargs="+", default=["Town1", "Town5"])
    ap.add_argument("--shifts", nargs="+", type=int, default=[0, 4, 8])
    ap.add_argument("--leads", nargs="+", type=int, default=[4, 8, 12])
    ap.add_argument("--drivers", type=int, default=24, help="population drivers per cell")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    torch.set_num_threads(1)
    out = {}
    for town in args.towns:
        swerve, decision = fit_decision(labelled_drives(town, 48, 11, 11, {"n_traffic": 2}))
        hit, false = decision.hit, decision.false
        cells = [(f"shift {k}", 23 + k, lambda _, k=k: (lambda info: int(info["explore_future"][k])))
                 for k in args.shifts] + [(f"lead {k}", 53 + k, lambda _, k=k: EarlyTurn(k)) for k in args.leads]
        drives = {name: labelled_drives(town, args.drivers, seed, seed, {"n_traffic": 2}, policy=policy)
                  for name, seed, policy in cells}
        every = [d for ds in drives.values() for d in ds]
        median, log_sd, gain = fit_memory(*outcome_rows(every, swerve), hit, false)
        table = []
        for name, ds in drives.items():
            room, late, R = outcome_rows(ds, swerve)
            p_react, held = late_probability_each(R, room), room - R
            p_memory = p_react + (1 - p_react) * memory_probability(held, median, log_sd)
            masks = [(name, torch.ones_like(late))] + [
                (f"{name}, held {a:g}..{b:g} s", (held >= a) & (held < b))
                for a, b in zip(HELD_BINS, HELD_BINS[1:], strict=False)]
            table += [{"cell": cell, "n": int(mask.sum()), "late": float(late[mask].double().mean()),
                       "reaction_only": float(false + (hit - false) * p_react[mask].mean()),
                       "with_memory": float(false + (hit - false) * p_memory[mask].mean())}
                      for cell, mask in masks if int(mask.sum()) > 0]
        out[town] = {"hit": hit, "false": false, "memory_median_s": median, "memory_log_sd": log_sd,
                     "loglik_gain": gain, "table": table}
        print(f"{town}: hit {hit}, false {false}; memory median {median} s, log-SD {log_sd}; log likelihood "
              f"{gain:+.1f} over none")
        for row in table:
            print(f"  {row['cell']:>26}: n {row['n']:4d}  late {row['late']:.3f}  reaction only "
                  f"{row['reaction_only']:.3f}  with memory {row['with_memory']:.3f}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
