"""Is adapt_driver's imagined gain where it leaves explore real? Replay a finished study's adapt_driver episodes in a town
(as ``departure_kinds.py`` does: the same seeds and recorded estimates) and, at every decision where the planner leaves
explore's action, score the three plans that decision compared (explore's plan, the base it had to beat: the cheapest
plan playing explore's action now, and the one chosen) with the planner's own cost on the *true* simulator
(:class:`~pernav.diagnostics.TrueDynamicsEnv`, ``--samples`` re-seeded futures from the live state, common random
numbers across the plans).

Per departure: its kind (``departure_kinds.kind``), the imagined gain (the model's base cost minus the chosen plan's,
mean over its rows) and the true gain (the same on the simulator, mean over the samples). The summary gives, over all
departures and per kind, the mean of each with a 95 % bootstrap CI, the share with a true gain above 0, and the
correlation of imagined with true gain: a departure whose true gain is about 0 while the model imagines tens is model
error. The chosen plan is also scored against explore's rule played *closed loop* on the same samples (each step's
explore action on the copy's own state: what explore would do, where explore's plan is imagined at today's speed):
a true gain over explore's plan that is not one over explore closed loop is the open-loop plan's, not the model's.

    .venv/bin/python docs/research/scripts/departure_truth.py runs/STUDY Town3 [--samples 10] [--json FILE]
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from departure_kinds import kind, replays  # noqa: E402

from pernav.diagnostics import TrueDynamicsEnv  # noqa: E402
from pernav.env.torchrl_env import navigation_of  # noqa: E402
from pernav.planner.retiming import RetimingPlanner  # noqa: E402
from pernav.study.stats import paired_difference  # noqa: E402
from pernav.trainer.collect import episode_metrics  # noqa: E402


def played_on_copies(nav, act, samples: int, seed: int, horizon: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Positions and goals ``[samples, 1, horizon, 2]`` of a rule ``act(copy) -> action`` played closed loop (each
    step's action on the copy's own state) on the same re-seeded copies as ``TrueDynamicsEnv(nav, samples, seed)``
    draws."""
    rng = np.random.default_rng(seed)
    pos = np.zeros((samples, 1, horizon, 2), dtype=np.float32)
    goal = np.zeros_like(pos)
    for m in range(samples):
        env, done = nav.branch(int(rng.integers(2**31 - 1))), False
        for h in range(horizon):
            done = TrueDynamicsEnv._advance(env, act(env), [0], h, pos[m], goal[m], done)
    return torch.from_numpy(pos), torch.from_numpy(goal)


def explore_closed_loop(nav, samples: int, seed: int, horizon: int, playbacks: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Explore's rule played closed loop on the copies (:func:`played_on_copies`), at the normal playback."""
    return played_on_copies(nav, lambda env: env.explore_action() * playbacks + (1 if playbacks > 1 else 0),
                            samples, seed, horizon)


class Checked:
    """The episode's DriverPlanner; after each decision that leaves explore, the three plans scored on the truth."""

    def __init__(self, policy, env, samples: int, seed: int) -> None:
        self.policy, self.env, self.samples, self.seed = policy, env, samples, seed
        self.found: list[dict] = []
        self.step = 0

    def __call__(self, td):
        planner: RetimingPlanner = self.policy.planner
        out = self.policy(td)
        action = int(out["action"])
        explore_action = int(td["explore_action"]) if "explore_action" in td.keys() else int(td["explore_future"][0])
        if action != explore_action and planner.last:  # planner.last: this call's searches
            r = planner.last[-1]
            seqs = r.candidates
            same = seqs[:, 0] == seqs[r.explore, 0]
            base = int(torch.where(same, r.costs, torch.full_like(r.costs, float("inf"))).argmin())
            rows = torch.stack([seqs[r.explore], seqs[base], seqs[r.chosen]])
            true_env = TrueDynamicsEnv(navigation_of(self.env), samples=self.samples, seed=self.seed + self.step)
            truth = RetimingPlanner(true_env, horizon=planner.horizon, route_weight=planner.route_weight,
                                    progress_weight=planner.progress_weight, playbacks=planner.playbacks)
            cost, _ = truth.costs(td, rows)  # [S, 3]
            closed = truth.score(td, *explore_closed_loop(navigation_of(self.env), self.samples, self.seed + self.step,
                                                          planner.horizon, planner.playbacks))[:, 0]  # [S]
            true_gain = cost[:, 1] - cost[:, 2]
            imagined, _ = planner.costs(td, rows)  # [M, 3]: the model's rows (its drivers) on the same three plans
            self.found.append({"step": self.step,
                               "kind": kind(action, explore_action, td["explore_future"].long().tolist()),
                               "imagined_gain": round(float(r.costs[base] - r.costs[r.chosen]), 2),
                               "imagined_vs_explore": round(float(r.costs[r.explore] - r.costs[r.chosen]), 2),
                               "imagined_rows_gain": [round(float(g), 2) for g in imagined[:, 1] - imagined[:, 2]],
                               "true_gain": round(float(true_gain.mean()), 2),
                               "true_gain_samples": [round(float(g), 2) for g in true_gain],
                               # the chosen plan against explore's rule played closed loop, on the same samples
                               "true_gain_vs_closed_loop": round(float((closed - cost[:, 2]).mean()), 2),
                               "explore_plan_minus_closed_loop": round(float((cost[:, 0] - closed).mean()), 2)})
        self.step += 1
        return out


def _mean_ci(values: list[float]) -> list[float] | None:
    if not values:
        return None
    d = paired_difference(values, [0.0] * len(values))
    return [round(d[k], 2) for k in ("mean", "low", "high")]


def summary(departures: list[dict]) -> dict:
    """Over ``departures`` (and per kind): imagined and true gain (mean, 95 % CI), the share truly gaining, and r."""
    def block(rows: list[dict]) -> dict:
        im = [r["imagined_gain"] for r in rows]
        tr = [r["true_gain"] for r in rows]
        closed = [r["true_gain_vs_closed_loop"] for r in rows]
        r = float(torch.corrcoef(torch.tensor([im, tr]))[0, 1]) if len(rows) > 2 else None
        return {"departures": len(rows), "imagined_gain": _mean_ci(im), "true_gain": _mean_ci(tr),
                "share_true_gain_positive": round(sum(t > 0 for t in tr) / len(tr), 3) if tr else None,
                "true_gain_vs_closed_loop": _mean_ci(closed),
                "share_closed_loop_gain_positive": round(sum(t > 0 for t in closed) / len(closed), 3) if tr else None,
                "r_imagined_true": None if r is None or r != r else round(r, 3)}

    kinds = collections.Counter(d["kind"] for d in departures)
    return {"all": block(departures), "kinds": {k: block([d for d in departures if d["kind"] == k])
                                                for k, _ in kinds.most_common()}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("study")
    parser.add_argument("town")
    parser.add_argument("--samples", type=int, default=10, help="true-simulator futures per departure (default 10)")
    parser.add_argument("--episodes", type=int, default=None, help="stop after this many episodes (default: all)")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    torch.set_num_threads(1)
    checked: list[Checked] = []

    def hook(policy, env):
        checked.append(Checked(policy, env, args.samples, seed=1_000 * len(checked)))
        return checked[-1]

    episodes, departures = [], []
    for label, route, trajectory, explore_cost, study_cost in replays(args.study, args.town, hook):
        cost = episode_metrics(trajectory)["tracking_cost"]
        found = [{"label": label, "route": route, **d} for d in checked[-1].found]
        departures += found
        episodes.append({"label": label, "route": route, "explore": explore_cost, "adapt_driver": cost,
                         "study_adapt_driver": study_cost, "departures": len(found)})
        print(label, route, round(explore_cost - cost, 1), [(d["kind"], d["imagined_gain"], d["true_gain"])
                                                           for d in found], flush=True)
        if args.episodes is not None and len(episodes) >= args.episodes:
            break
    matches = sum(abs(e["adapt_driver"] - e["study_adapt_driver"]) < 1e-6 * max(1.0, abs(e["study_adapt_driver"]))
                  for e in episodes)
    out = {"study": "/".join(Path(args.study).parts[-2:]), "town": args.town, "samples": args.samples,
           "replay_matches": [matches, len(episodes)], **summary(departures),
           "departures": departures, "episodes": episodes}
    print(json.dumps({k: out[k] for k in ("replay_matches", "all")}, indent=1))
    if args.json:
        # the summary indented, each departure and episode on a line of its own
        head = json.dumps({k: v for k, v in out.items() if k not in ("departures", "episodes")}, indent=1)[:-2]
        rows = {k: ",\n  ".join(json.dumps(r) for r in out[k]) for k in ("departures", "episodes")}
        Path(args.json).write_text(head + "".join(f',\n "{k}": [\n  {v}\n ]' for k, v in rows.items()) + "\n}\n")


if __name__ == "__main__":
    main()
