"""Can the planner's own 16-step cost rank the constant shifts as ``best_shift`` does, on the *true* simulator?

``model_shift.py`` asks whether the hybrid model, on a driver's true parameters, ranks the shifts of explore's rule as
the whole episodes do (``planner_vs_best_shift.py``); it does not. This asks the question before it: with a perfect
model, does the planner's score (``RetimingPlanner.score``, summed over the states of explore's drive) choose the
shift the episodes choose? At every step of explore's drive on the sweep approach where the shifts' plans differ,
each shift is played **closed loop** on ``--samples`` re-seeded copies of the live simulator (common random numbers
across the shifts: copy ``m`` of every shift has the same seed), as :class:`~pernav.planner.retiming.ShiftedExplore`
plays on the real car: ``k`` > 0 says what explore's plan says ``k`` steps ahead of the copy's car now, ``k`` < 0
what explore said ``-k`` steps before. Each shift's 16-step cost over ``k = 0``'s is summed over the states and the
drives. Beside it, the hybrid model on the true parameters (open loop, as ``model_shift.py``) on the same states;
and both again with each step's charge capped (``--step-cap``, ``RetimingPlanner.step_cap``: a missed turn then
costs about what it costs an episode, not its squared metres), and with the env's own step cost alone (no route or
progress term: what an episode charges; the simulator re-routes after a miss, the model does not).

    .venv/bin/python docs/research/scripts/shift_truth.py --seeds 5 --samples 4 --json out.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

from pernav.env.planning import explore_plan
from pernav.env.sweep import sweep_route
from pernav.env.torchrl_env import explore_module, navigation_of
from pernav.model.driver import DriverImaginedEnv
from pernav.planner.retiming import Departure, RetimingPlanner
from pernav.study.driver_rounds import SHIFTS
from pernav.trainer.collect import drive, history_env
from pernav.world.constants import Instruction

sys.path.insert(0, str(Path(__file__).resolve().parent))
from departure_truth import played_on_copies  # noqa: E402
from model_shift import shift_sequences  # noqa: E402
from planner_vs_best_shift import CONFIG, DRIVER_PLANNER, DRIVERS, OPTIONS, true_params  # noqa: E402

#: the scores compared: the planner's as it is, each step's charge capped, and the env's own step cost alone (no
#: route or progress term: what an episode charges, where the simulator re-routes after a miss)
VARIANTS = ("as_is", "capped", "tracking")
SUMS = tuple(f"{who}_{v}" for v in VARIANTS for who in ("truth", "model"))


def shifted_action(nav, k: int) -> int:
    """What explore's rule shifted by ``k`` steps plays on ``nav`` now (as ShiftedExplore on the env's plan)."""
    if k >= 0:
        instruction = explore_plan(nav._explore, nav.nav_view(), [], k + 1, 0)[k]
    else:
        instruction = ([Instruction.NONE] * -k + list(nav._explore_past))[k]  # padded as the env's explore_plan
    return nav.encode(int(instruction))


def closed_loop(nav, k: int, samples: int, seed: int, horizon: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Positions and goals ``[samples, 1, horizon, 2]`` of shift ``k`` played closed loop on re-seeded copies."""
    return played_on_copies(nav, lambda env: shifted_action(env, k), samples, seed, horizon)


class Scored:
    """Explore, and at each step where the shifts' plans differ, every shift scored on the truth and on the model."""

    def __init__(self, env, planner: RetimingPlanner, samples: int, seed: int, cap: float) -> None:
        self.env, self.planner, self.samples, self.seed, self.cap = env, planner, samples, seed, cap
        self.policy = explore_module()
        self.sums = {key: dict.fromkeys(SHIFTS, 0.0) for key in SUMS}
        rw, pw = planner.route_weight, planner.progress_weight
        self.variants = {"as_is": (None, rw, pw), "capped": (cap, rw, pw), "tracking": (None, 0.0, 0.0)}
        self.states, self.step = 0, 0

    def __call__(self, td):
        horizon = self.planner.horizon
        seqs = shift_sequences(td, SHIFTS, horizon)
        explore = SHIFTS.index(0)
        if not bool((seqs == seqs[explore]).all()):
            nav = navigation_of(self.env)
            driven = [closed_loop(nav, k, self.samples, self.seed + self.step, horizon) for k in SHIFTS]
            imagined = self.planner._imagine(td, seqs)
            for variant, (cap, route_weight, progress_weight) in self.variants.items():
                saved = self.planner.step_cap, self.planner.route_weight, self.planner.progress_weight
                self.planner.step_cap, self.planner.route_weight, self.planner.progress_weight = \
                    cap, route_weight, progress_weight
                true = [float(self.planner.score(td, *d).mean()) for d in driven]
                model = self.planner.score(td, *imagined).mean(0)
                self.planner.step_cap, self.planner.route_weight, self.planner.progress_weight = saved
                for i, k in enumerate(SHIFTS):
                    self.sums[f"truth_{variant}"][k] += true[i] - true[explore]
                    self.sums[f"model_{variant}"][k] += float(model[i] - model[explore])
            self.states += 1
        self.step += 1
        return self.policy(td)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--first-seed", type=int, default=0, help="the seeds are first-seed .. first-seed + seeds - 1")
    parser.add_argument("--samples", type=int, default=4)
    parser.add_argument("--drivers", nargs="+", default=list(DRIVERS), choices=list(DRIVERS))
    parser.add_argument("--step-cap", type=float, default=10.0, help="the capped sums' cap (RetimingPlanner.step_cap)")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    report = {}
    for name in args.drivers:
        profile, context = DRIVERS[name]
        planner = RetimingPlanner(DriverImaginedEnv([true_params(profile, context)]),
                                  departure=Departure(**DRIVER_PLANNER["departure"]), **OPTIONS)
        sums, states = {key: dict.fromkeys(SHIFTS, 0.0) for key in SUMS}, 0
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            env = history_env("Town1", {"route": sweep_route(), "user": profile, "context": context}, config=CONFIG,
                              seed=seed)
            scored = Scored(env, planner, args.samples, seed * 1000, args.step_cap)
            drive(env, scored)
            for key in SUMS:
                for k in SHIFTS:
                    sums[key][k] += scored.sums[key][k]
            states += scored.states
        report[name] = {"states": states,
                        **{f"{key}_shift": min(v, key=lambda k, v=v: (v[k], abs(k))) for key, v in sums.items()},
                        **{f"{key}_over_explore": {str(k): round(x, 1) for k, x in v.items()} for key, v in sums.items()}}
        print(name, json.dumps(report[name]), flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"seeds": args.seeds, "first_seed": args.first_seed, "samples": args.samples,
                       "step_cap": args.step_cap, "drivers": report}, f, indent=1)


if __name__ == "__main__":
    main()
