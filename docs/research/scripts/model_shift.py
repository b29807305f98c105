"""Would a shift of explore's rule chosen on the hybrid model match ``best_shift``? (a policy-level search, measured)

The re-timing planner leaves explore only for a per-decision gain past its margin, and the gains ``best_shift`` finds
are a few per episode: too small for any one decision. A search over the constant shifts themselves, summed over a
whole drive, would average the model's errors over many states. This measures whether the model, given a driver's
*true* parameters (as ``planner_vs_best_shift.py``; allowed here: a check of the model, not a learner), ranks the
shifts as the true simulator does on the sweep approach. At every step of explore's drive, each shift's plan
(``k`` > 0: explore's plan ``k`` steps ahead; ``k`` < 0: its prompts of ``-k`` steps ago, then its plan) is imagined
over the planner's horizon; the imagined cost over explore's plan is summed over the steps and the drives.

    .venv/bin/python docs/research/scripts/model_shift.py --seeds 5 [--step-cap 10]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

from pernav.env.sweep import sweep_route
from pernav.env.torchrl_env import explore_module
from pernav.model.driver import DriverImaginedEnv
from pernav.planner.retiming import Departure, RetimingPlanner
from pernav.study.driver_rounds import SHIFTS
from pernav.trainer.collect import drive, history_env

sys.path.insert(0, str(Path(__file__).resolve().parent))
from planner_vs_best_shift import CONFIG, DRIVER_PLANNER, DRIVERS, OPTIONS, true_params  # noqa: E402  (its approach and drivers)

PLAN_SHIFT = CONFIG["plan_shift"]  # how far back the env's explore_plan reaches


def shift_sequences(root, shifts: tuple[int, ...], horizon: int) -> torch.Tensor:
    """``[len(shifts), horizon]``: each shift's plan from ``root`` (``k`` > 0: explore's plan ``k`` steps ahead;
    ``k`` < 0: its prompts of ``-k`` steps ago, then its plan), as ``ShiftedExplore`` would play it at today's speed."""
    future, plan = root["explore_future"].long(), root["explore_plan"].long()
    return torch.stack([future[k:k + horizon] if k >= 0 else
                        torch.cat([plan[PLAN_SHIFT + k:PLAN_SHIFT], future[:horizon + k]]) for k in shifts])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--step-cap", type=float, default=None,
                        help="cap each imagined step's charge (RetimingPlanner.step_cap): a miss costs an episode's scale")
    parser.add_argument("--drivers", nargs="+", default=list(DRIVERS), choices=list(DRIVERS))
    parser.add_argument("--closed-loop", action="store_true",
                        help="imagine each shift k >= 0 closed loop on the env's explore table "
                             "(RetimingPlanner.closed_loop); the shifts below 0 are left out")
    args = parser.parse_args()
    horizon = OPTIONS["horizon"]
    config = {**CONFIG, "explore_table": True} if args.closed_loop else CONFIG
    shifts = tuple(k for k in SHIFTS if k >= 0) if args.closed_loop else SHIFTS
    for name in args.drivers:
        profile, context = DRIVERS[name]
        planner = RetimingPlanner(DriverImaginedEnv([true_params(profile, context)]),
                                  departure=Departure(**DRIVER_PLANNER["departure"]), **OPTIONS)
        planner.step_cap = args.step_cap
        totals = dict.fromkeys(shifts, 0.0)
        for seed in range(args.seeds):
            env = history_env("Town1", {"route": sweep_route(), "user": profile, "context": context}, config=config,
                              seed=seed)
            trajectory = drive(env, explore_module())
            for t in range(trajectory.shape[0]):
                root = trajectory[t]
                seqs = shift_sequences(root, shifts, horizon)
                explore = shifts.index(0)
                if bool((seqs == seqs[explore]).all()):
                    continue
                if args.closed_loop:
                    pos, goal, _ = planner.imagine_closed(root, seqs)
                    mean = planner.score(root, pos, goal).mean(0)
                else:
                    mean = planner.costs(root, seqs)[0].mean(0)
                for i, k in enumerate(shifts):
                    totals[k] += float(mean[i] - mean[explore])
        print(name, "the model's shift:", min(totals, key=totals.get),
              "imagined cost over explore's, summed:", {k: round(v, 1) for k, v in totals.items()})


if __name__ == "__main__":
    main()
