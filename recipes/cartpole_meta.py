"""The paper's Algorithm 1 on a second task: CartPole whose dynamics change every round.

Shows that pernav's TorchRL parts carry a task with no navigation in it. Takes about 6 minutes with the
defaults on a 2-core laptop CPU (``--K 2``: 8 minutes); the figures are in docs/components.md.

No navigation code: the same TorchRL parts pernav's study uses, on gymnasium's CartPole-v1 with a different
pole length, pole mass and motor per round (the motor's force 6-14 N, and in half of the tasks wired backwards:
GrBAL's "motor malfunction", Nagabandi et al. 2019):

* ``HistoryWindow`` (the last K (state, action) rows) on a TorchRL ``GymWrapper``;
* ``DynamicsModel(state_dim=4, n_actions=2, delta="plain")``, trained with ``RoundBuffers`` and ``FTMLTrainer``;
* ``adapt`` (one gradient step on the round's first trajectory tau, test-time step-halving as in the study);
* ``DiscreteTreeSearchPlanner`` over an ``ImaginedEnv`` whose reward is the task's (known) reward.

Rounds: offline rounds (random-policy data, a warm start of plain updates, then FTML), then online rounds: each
new task gives tau (one random episode), then every method drives the same seeded episodes:

* ``adapt``: the meta model adapted on tau, planned with (the paper's method);
* ``meta``: the meta model without adaptation (an ablation: what the single step adds);
* ``sysid``: a model trained by plain maximum likelihood on the same data stream, never adapted (SysID);
* ``random``: uniformly random actions.

The round's tau and adapt's episodes are then added to the data and both models take their updates (FTML for
the meta model, plain for SysID). The task reward (also the planner's): ``1 - 0.5 |x - 1|`` (at least 0) per
step while the pole is up (|theta| < 12 deg, |x| < 2.4): balance, and hold the cart at x = 1 m.

Writes ``results.json`` (every return), ``summary.md`` (paired CIs over seeds x rounds) and ``returns.png``.

    .venv/bin/python recipes/cartpole_meta.py runs/cartpole --seeds 0 1 2 3 4
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.envs import GymWrapper, TransformedEnv
from tqdm import tqdm

from pernav.model import DynamicsModel, ImaginedEnv, adapt
from pernav.model.losses import using
from pernav.planner import DiscreteTreeSearchPlanner
from pernav.study.stats import bootstrap_ci, paired_difference
from pernav.trainer import FTMLTrainer, RoundBuffers, TrainConfig
from pernav.transforms import HistoryWindow

METHODS = ("adapt", "meta", "sysid", "random")
X_GOAL, X_LIMIT, THETA_LIMIT = 1.0, 2.4, 12 * 2 * np.pi / 360  # CartPole-v1's own limits


def task_reward(next_state: torch.Tensor) -> torch.Tensor:
    """The per-step reward of a transition into ``next_state`` ``[..., 4]``: 1 for an upright pole with the cart
    at ``X_GOAL``, less for a leaning pole or a distant cart, 0 once the pole is down (the episode ends)."""
    x, theta = next_state[..., 0], next_state[..., 2]
    alive = (x.abs() < X_LIMIT) & (theta.abs() < THETA_LIMIT)
    return (1.0 - 0.5 * (theta / THETA_LIMIT) ** 2 - 0.25 * (x - X_GOAL).abs()).clamp(min=0.0) * alive


def failed(next_state: torch.Tensor) -> torch.Tensor:
    return (next_state[..., 0].abs() >= X_LIMIT) | (next_state[..., 2].abs() >= THETA_LIMIT)


def draw_task(seed: int, round_: int) -> dict[str, float]:
    """A round's dynamics: pole length and mass, motor force (negative: wired backwards)."""
    rng = np.random.default_rng([seed, round_, 32])
    sign = -1.0 if rng.random() < 0.5 else 1.0
    return {"length": float(rng.uniform(0.3, 1.2)), "masspole": float(rng.uniform(0.05, 0.5)),
            "force_mag": sign * float(rng.uniform(6.0, 14.0))}


def make_env(task: dict[str, float], K: int, max_steps: int) -> TransformedEnv:
    """CartPole-v1 with the task's dynamics, as a TorchRL env with a HistoryWindow."""
    gym_env = gym.make("CartPole-v1", max_episode_steps=max_steps)
    cart = gym_env.unwrapped
    cart.length, cart.masspole, cart.force_mag = task["length"], task["masspole"], task["force_mag"]
    cart.total_mass = cart.masspole + cart.masscart
    cart.polemass_length = cart.masspole * cart.length
    return TransformedEnv(GymWrapper(gym_env, categorical_action_encoding=True), HistoryWindow(K=K))


class RandomPolicy(torch.nn.Module):
    """Uniform random actions from its own generator (seeded: paired episodes see the same draws)."""

    def __init__(self, seed: int) -> None:
        super().__init__()
        self.generator = torch.Generator().manual_seed(seed)

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        td.set("action", torch.randint(2, td.shape, generator=self.generator))
        return td


@torch.no_grad()
def episode(env: TransformedEnv, policy, seed: int, max_steps: int) -> TensorDictBase:
    env.set_seed(seed)
    return env.rollout(max_steps, policy=policy, break_when_any_done=True)


def episode_return(trajectory: TensorDictBase) -> float:
    return float(task_reward(trajectory["next", "observation"]).sum())


def trajectory_data(trajectory: TensorDictBase) -> TensorDictBase:
    return trajectory.select("observation", "action", "history", ("next", "observation"))


def run_seed(seed: int, args: argparse.Namespace) -> dict[str, list[float]]:
    """One seed's online returns per method and round (``[online][episodes]``)."""
    torch.manual_seed(seed)
    train = TrainConfig(lr=1e-3, batch=64, L=args.L, alpha=args.alpha, K=args.K, hidden=[64, 64],
                        rounds_per_update=4, max_grad_norm=100.0, backtrack=0.5)
    model = DynamicsModel(state_dim=4, n_actions=2, K=args.K, hidden=train.hidden, delta="plain")
    sysid_model = copy.deepcopy(model)  # the same initial weights
    buffers = RoundBuffers(L=args.L, seed=seed)
    meta, sysid = FTMLTrainer(model, buffers, train, seed=seed), FTMLTrainer(sysid_model, buffers, train, seed=seed)
    # offline rounds: random-policy data of each task, the first episode its tau
    for r in range(args.offline):
        env = make_env(draw_task(seed, r), args.K, args.max_steps)
        for e in range(args.offline_episodes):
            buffers.add(r, trajectory_data(episode(env, RandomPolicy(1000 * seed + 10 * r + e), 10_000 * seed + 100 * r + e,
                                                   args.max_steps)), tau=e == 0)
    meta.fit_normalization()
    sysid_model.load_state_dict(model.state_dict())  # the same normalization statistics
    for trainer, is_meta in ((meta, True), (sysid, False)):
        trainer.train(args.warm_updates, meta=False)
        trainer.train(args.offline_updates, meta=is_meta)
    planners = {"meta": (model, None), "sysid": (sysid_model, None)}
    out: dict[str, list[list[float]]] = {m: [] for m in METHODS}
    for r in range(args.offline, args.offline + args.online):
        task = draw_task(seed, r)
        env = make_env(task, args.K, args.max_steps)
        tau = trajectory_data(episode(env, RandomPolicy(1000 * seed + 10 * r), 10_000 * seed + 100 * r, args.max_steps))
        with torch.enable_grad():
            adapted = adapt(model, tau, alpha=train.alpha, L=train.L, first_order=True, max_norm=train.max_grad_norm,
                            backtrack=train.backtrack).detach()
        runs = {**planners, "adapt": (model, adapted)}
        adapt_drives = []
        for e in range(args.episodes):
            episode_seed = 10_000 * seed + 100 * r + 50 + e  # the same start for every method
            for method in METHODS:
                if method == "random":
                    traj = episode(env, RandomPolicy(episode_seed), episode_seed, args.max_steps)
                else:
                    net, params = runs[method]
                    planner = DiscreteTreeSearchPlanner(ImaginedEnv(net, lambda s, a, n: task_reward(n), failed),
                                                        planning_horizon=args.horizon)
                    with using(net, params):
                        traj = episode(env, planner, episode_seed, args.max_steps)
                    if method == "adapt":
                        adapt_drives.append(trajectory_data(traj))
                if e == 0:
                    out[method].append([])
                out[method][-1].append(episode_return(traj))
        buffers.add(r, tau, tau=True)
        for drive in adapt_drives:
            buffers.add(r, drive)
        meta.train(args.online_updates, meta=True)
        sysid.train(args.online_updates, meta=False)
    return out


def summarize(results: dict[str, dict[str, list[list[float]]]], args: argparse.Namespace) -> str:
    """Markdown: mean return per method, and paired differences (rounds after the first online round)."""
    def cells(method: str, skip_first: bool) -> list[float]:
        return [float(np.mean(eps)) for s in results.values() for i, eps in enumerate(s[method])
                if not (skip_first and i == 0)]

    lines = [f"# CartPole with changing dynamics: Algorithm 1 with pernav's parts ({len(results)} seeds, "
             f"{args.online} online rounds, {args.episodes} episodes per method and round)", "",
             "| method | mean return per episode, all online rounds [95 % CI] |", "|---|---|"]
    for method in METHODS:
        mean, lo, hi = bootstrap_ci(cells(method, False))
        lines.append(f"| {method} | {mean:.1f} [{lo:.1f}, {hi:.1f}] |")
    lines += ["", "Paired differences over (seed, online round) cells after each seed's first online round "
              "(same tasks and episode seeds):", "", "| comparison | mean [95 % CI] | n |", "|---|---|---|"]
    for other in ("sysid", "meta", "random"):
        d = paired_difference(cells(other, True), cells("adapt", True))
        lines.append(f"| adapt - {other} | {-d['mean']:+.1f} [{-d['high']:+.1f}, {-d['low']:+.1f}] | {d['n']} |")
    return "\n".join(lines) + "\n"


def plot(results: dict[str, dict[str, list[list[float]]]], path: Path, args: argparse.Namespace) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.4))
    rounds = np.arange(1, args.online + 1)
    for method in METHODS:
        per_round = np.array([[np.mean(eps) for eps in s[method]] for s in results.values()])  # [seeds, rounds]
        ci = np.array([bootstrap_ci(per_round[:, i]) for i in range(per_round.shape[1])])
        ax.plot(rounds, ci[:, 0], marker="o", label=method)
        ax.fill_between(rounds, ci[:, 1], ci[:, 2], alpha=0.15)
    ax.set_xlabel("online round (a new task each round)")
    ax.set_ylabel("return per episode")
    ax.set_title(f"CartPole, dynamics changing every round ({len(results)} seeds, 95 % CI)")
    ax.legend(ncol=len(METHODS), loc="upper center", bbox_to_anchor=(0.5, -0.16), frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    # every option has a help string: ArgumentDefaultsHelpFormatter shows the default only of those
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("out", type=Path, help="a new folder for results.json, summary.md, returns.png")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4], help="seeds (one full run each)")
    parser.add_argument("--offline", type=int, default=8, help="offline rounds (tasks)")
    parser.add_argument("--offline-episodes", type=int, default=4, help="random-policy episodes per offline round")
    parser.add_argument("--online", type=int, default=6, help="online rounds (tasks)")
    parser.add_argument("--episodes", type=int, default=2, help="episodes per method and online round")
    parser.add_argument("--max-steps", type=int, default=150, help="steps per episode at most")
    parser.add_argument("--horizon", type=int, default=6, help="planning horizon (2^H sequences)")
    parser.add_argument("--K", type=int, default=1, help="history window of the model (1: the current state only)")
    parser.add_argument("--L", type=int, default=3, help="L-step loss length")
    parser.add_argument("--alpha", type=float, default=0.05, help="adaptation step")
    parser.add_argument("--warm-updates", type=int, default=300, help="plain updates of the offline warm start")
    parser.add_argument("--offline-updates", type=int, default=300,
                        help="updates after the warm start (FTML for meta, plain for sysid)")
    parser.add_argument("--online-updates", type=int, default=30, help="updates of each model after each online round")
    args = parser.parse_args(argv)
    if args.out.exists():
        print(f"error: {args.out} exists; choose a new folder (nothing is overwritten)", file=sys.stderr)
        return 2
    if min(args.offline, args.online, args.episodes, args.horizon, args.K, args.L) < 1:
        print("error: --offline, --online, --episodes, --horizon, --K and --L must be >= 1", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    results = {str(seed): run_seed(seed, args) for seed in tqdm(args.seeds, desc="seeds")}
    args.out.mkdir(parents=True)
    summary = summarize(results, args)
    config = {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()}
    (args.out / "results.json").write_text(json.dumps({"config": config, "returns": results,
                                                       "seconds": round(time.perf_counter() - t0, 1)}, indent=1))
    (args.out / "summary.md").write_text(summary)
    plot(results, args.out / "returns.png", args)
    print(summary)
    print(f"{time.perf_counter() - t0:.0f} s; wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
