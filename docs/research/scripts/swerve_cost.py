"""What a swerve costs on the sweep approach: the tracking cost and the car's distance from the route around each one.

``shift_events.py`` finds that the clear shifts of user3 (truck in fog) and the very slow driver come with their
swerves gone, and the twenty-second session guessed that a swerve runs the car wide, which the hybrid model does not
imagine. This checks that guess: it drives the episodes ``planner_vs_best_shift.py`` drives under each constant shift
(``ShiftedExplore``), records the world's swerve counter after every step (reading it is allowed here: a check of the
model, not a learner) and reports, per shift, the episodes' mean cost, and for each swerve the step costs and the
car's distance from the route (its nearest ``route_ahead`` point) from two steps before its onset to seven after.

    .venv/bin/python docs/research/scripts/swerve_cost.py --driver user3_truck_fog --shifts 0 3 --seeds 10 --json out.json
"""

from __future__ import annotations

import statistics
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from shift_events import by_shift, shifted  # noqa: E402

from pernav.env.torchrl_env import navigation_of  # noqa: E402
from pernav.trainer.collect import MAX_STEPS  # noqa: E402

BEFORE, AFTER = 2, 8  # steps around a swerve's onset reported


def episode(name: str, k: int, seed: int) -> dict:
    """One episode of ``name``'s driver under shift ``k``: its cost, its largest distance from the route, and the
    window around each swerve."""
    env, policy = shifted(name, k, seed)
    nav, swerves = navigation_of(env), []
    t = env.rollout(MAX_STEPS, policy=policy, break_when_any_done=True,
                    callback=lambda _env, _td: swerves.append(nav.world.events.swerves))
    counts = torch.tensor([0, *swerves[:t.shape[0]]])
    onsets = (counts.diff() > 0).nonzero().flatten().tolist()
    cost = t["next", "step_cost"]
    off = (t["next", "route_ahead"] - t["next", "observation"][:, None, :2]).norm(dim=-1).min(-1).values
    window = [{"step": s, "cost": [round(float(c), 1) for c in cost[max(s - BEFORE, 0):s + AFTER]],
               "off_route_m": [round(float(d), 2) for d in off[max(s - BEFORE, 0):s + AFTER]]} for s in onsets]
    return {"seed": seed, "cost": round(float(cost.sum()), 1), "max_off_route_m": round(float(off.max()), 2),
            "swerves": window}


def summary(rows: list[dict]) -> dict:
    """A shift's mean cost, its episodes with a swerve, the farthest from the route and the dearest step in a swerve."""
    windows = [w for r in rows for w in r["swerves"]]
    return {"mean_cost": round(statistics.mean(r["cost"] for r in rows), 1),
            "episodes_with_a_swerve": sum(bool(r["swerves"]) for r in rows),
            "largest_off_route_m": max(r["max_off_route_m"] for r in rows),
            "largest_step_cost_in_a_swerve": max((max(w["cost"]) for w in windows), default=None)}


def main() -> None:
    by_shift(__doc__, episode, summary, (0, 3))


if __name__ == "__main__":
    main()
