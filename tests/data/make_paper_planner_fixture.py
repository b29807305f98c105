"""Decisions of the paper planner on five seeded, deliberately explosive models: the fixture of
tests/planner/test_discrete_planner.py. It runs on the current tree; regenerate it (and review the diff of decisions)
only when a change to the planner is meant to change what it decides::

    .venv/bin/python tests/data/make_paper_planner_fixture.py tests/data/paper_planner.pt

The file was first recorded with the planner's original level-by-level search and reproduced by the present
search to the last bit on the machine that recorded it; the test compares actions exactly and costs with a
relative tolerance, since another CPU rounds the MLP's matrix products differently.
"""

import sys

import torch
from tensordict import TensorDict

from pernav.model import DynamicsModel
from pernav.model.navigation import ImaginedNavigationEnv, make_world_model
from pernav.planner import TreeSearchPlanner

S = 14
CASES = [dict(n_actions=7, horizon=5, mask=True), dict(n_actions=7, horizon=4, mask=False, penalty=2.0),
         dict(n_actions=21, horizon=3, beam=16), dict(n_actions=7, horizon=4, goal_source="route"),
         dict(n_actions=21, horizon=3, mask=True)]


def make_cases() -> list[dict]:
    """The five cases: model, roots, and the planner's actions, sequences and one-root-at-a-time costs."""
    out = []
    for c, case in enumerate(CASES):
        case = dict(case)
        A = case.pop("n_actions")
        torch.manual_seed(c)
        model = DynamicsModel(n_actions=A, hidden=(32, 32))
        g = torch.Generator().manual_seed(c)
        N, H, shift = 40, case["horizon"], 2
        hist = torch.randn(N, 5, S + A, generator=g) * 3
        hist[..., S:] = torch.nn.functional.one_hot(torch.randint(A, (N, 5), generator=g), A).float()
        hist[:, -1, S:] = 0
        model.fit_normalization(hist, torch.randint(A, (N,), generator=g), torch.randn(N, S, generator=g) * 3)
        with torch.no_grad():
            for p in model.parameters():
                p.mul_(3.0)  # spread the costs so that the bonus decides some roots and not others
        roots = TensorDict({"observation": hist[:, -1, :S].clone(), "history": hist,
                            "plan_goals": torch.randn(N, H, 2, generator=g) * 5,
                            "explore_plan": torch.randint(7, (N, H + 2 * shift), generator=g),
                            "action_mask": torch.rand(N, H, A, generator=g) < 0.6}, [N])
        roots["action_mask"][..., 0] = True
        planner = TreeSearchPlanner(ImaginedNavigationEnv(make_world_model(model)), shift=shift, bonus=5.0, **case)
        actions = planner(roots.clone())["action"]
        seqs = planner.last.actions.clone()
        costs = []
        for i in range(N):
            planner(roots[i].clone())
            costs.append(-planner.last.returns[0])
        out.append({"case": {"n_actions": A, **case, "shift": shift, "bonus": 5.0}, "model": model.state_dict(),
                    "roots": roots.to_dict(), "actions": actions, "sequences": seqs, "costs": torch.stack(costs)})
    return out


if __name__ == "__main__":
    torch.save(make_cases(), sys.argv[1])
