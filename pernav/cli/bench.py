"""``pernav bench``: benchmarks: speeds as ratios against a reference measured in the same run.

The machines are shared and noisy, so absolute figures are printed for information and targets are
stated on ratios.

Example:
    >>> figs = run_benchmarks("sim", quick=True)
    >>> figs["sim"]["ratio_vs_intersection"] > 0
    True
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import statistics
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import highway_env  # noqa: F401  (registers the stock ids)
import numpy as np
import torch
from tensordict import TensorDict

from pernav.cli.common import UsageError
from pernav.env.navigation import NavigationEnv
from pernav.env.policies import belief_policy, explore_policy
from pernav.env.torchrl_env import explore_module
from pernav.learners.belief import AnswerDetector, BeliefTracker, DecisionPrior, ReactionBelief
from pernav.learners.driver import DriverBelief, DriverPlanner, DriverPrior, DriverTracker
from pernav.learners.outcomes import SwerveDetector
from pernav.learners.timing import N_FEATURES, TimingModel
from pernav.model import DynamicsModel, ImaginedEnv, adapt, multistep_loss
from pernav.model.adapt import meta_parameters
from pernav.model.egocentric import GX, GY, X, Y, road_of
from pernav.model.navigation import ImaginedNavigationEnv, make_world_model
from pernav.planner import DiscreteTreeSearchPlanner, RetimingPlanner, TreeSearchPlanner
from pernav.play.livebench import bench_live
from pernav.play.loop import PlaySession
from pernav.play.options import PlayOptions
from pernav.study.config import preset
from pernav.study.driver_rounds import DRIVER_PLANNER
from pernav.trainer.collect import drive, history_env
from pernav.world.cost import tracking_cost


def _steps_per_second(env, policy, steps: int, seed: int = 0, options: dict | None = None) -> float:
    _, info = env.reset(seed=seed, options=options or {})
    n, t0 = 0, time.perf_counter()
    while n < steps:
        _, _, terminated, truncated, info = env.step(policy(info))
        n += 1
        if terminated or truncated:
            _, info = env.reset(options=options or {})
    return n / (time.perf_counter() - t0)


def bench_sim(quick: bool = False) -> dict[str, Any]:
    """NavigationEnv steps/s (multi-junction town, 8 traffic cars, explore policy) vs highway-env's
    stock ``intersection-v2`` (one junction) stepped with random actions, in the same process."""


    steps = 60 if quick else 400
    ours = NavigationEnv("Town3", config={"n_traffic": 8})
    ours_rate = _steps_per_second(ours, lambda info: info["explore_action"], steps, options={"route": 0})
    # The stock env is created after ours: creating it mutates IDMVehicle class constants
    # process-wide (highway-env's intersection env sets them on creation); our traffic does not read them.
    stock = gym.make("intersection-v2")
    stock.action_space.seed(0)
    stock_rate = _steps_per_second(stock, lambda info: stock.action_space.sample(), steps // 4)
    stock.close()
    return {
        "pernav_steps_per_s": round(ours_rate, 1),
        "intersection_v2_steps_per_s": round(stock_rate, 1),
        "ratio_vs_intersection": round(ours_rate / stock_rate, 2),
        "pernav_frames_per_step": ours.config["frequency"],
        "intersection_v2_frames_per_step": stock.unwrapped.config["simulation_frequency"]
        // stock.unwrapped.config["policy_frequency"],
        "target": "ratio_vs_intersection >= 4.0 (traffic of the current world)",
    }


def _median_ms(times: list[float]) -> float:
    return round(1000 * statistics.median(times), 3)


def _p95_ms(times: list[float]) -> float:
    return round(1000 * float(np.percentile(times, 95)), 3)


def _timed(fn, *args) -> tuple[float, Any]:
    t0 = time.perf_counter()
    out = fn(*args)
    return time.perf_counter() - t0, out


def _recorded_states(towns: dict[str, list[int]], config: dict, K: int = 5):
    """Each step's tensordict of explore-policy episodes (the planner's real inputs), concatenated."""


    trajectories = [drive(history_env(town, {"route": r, "user": "user1"}, config=config, seed=r, K=K),
                          explore_module())
                    for town, routes in towns.items() for r in routes]
    return torch.cat(trajectories)


def _mlp_flops(model) -> int:
    """Multiply-adds x 2 of one MLP evaluation."""
    return 2 * sum(layer.in_features * layer.out_features for layer in _linears(model))


def _linears(model) -> list:

    return [m for m in model.net.modules() if isinstance(m, torch.nn.Linear)]


def _matmul_chain_seconds(model, batch_sizes: list[int], repeats: int) -> float:
    """Median time of a bare ``x @ W.T + b`` (+ReLU) chain with the model's layer shapes over the same
    batch sizes as the search's levels: the attainable rate of this CPU for this work."""
    layers = [(m.weight.detach(), m.bias.detach()) for m in _linears(model)]
    inputs = [torch.randn(n, layers[0][0].shape[1]) for n in batch_sizes]

    def chain() -> None:
        for x in inputs:
            for i, (w, b) in enumerate(layers):
                x = torch.addmm(b, x, w.t())
                if i + 1 < len(layers):
                    x = torch.relu(x)

    chain()
    return statistics.median(_timed(chain)[0] for _ in range(repeats))


def bench_planner(quick: bool = False) -> dict[str, Any]:
    """TreeSearchPlanner per-decision latency at the paper's size (MLP [256, 256, 256], 7 actions, H=5,
    K=5; random init, normalization fitted on explore-policy data), all in one process:

    * exhaustive level-by-level search (mask all-true) vs a flat enumeration of the same tree (every sequence
      rolled out on its own, the reference) on the same states;
    * the masked search (the planner as deployed) on states recorded from real Town1/Town3 episodes;
    * the exhaustive search's achieved FLOP/s vs a bare matmul chain of the same layer shapes and batches;
    * the 21-action beam search (beam 64, masked) on states from a 21-action env;
    * the generic :class:`~pernav.planner.DiscreteTreeSearchPlanner` on a toy model env (a CartPole-sized
      :class:`~pernav.model.ImaginedEnv`: 4-d state, 2 actions, horizon 8, MLP [64, 64]; batch 1 and 16).
    """


    torch.manual_seed(0)
    routes = {"Town1": [0], "Town3": [0]} if quick else {"Town1": [0, 1, 2], "Town3": [0, 1, 2]}
    fast = {"n_traffic": 2}
    data = _recorded_states(routes, fast)
    model = DynamicsModel()
    model.fit_normalization(data["history"], data["action"], data["next", "observation"])
    planner = TreeSearchPlanner(ImaginedNavigationEnv(make_world_model(model)))
    exhaustive, level_t = _bench_exhaustive(planner, data, quick)
    n_masked = 40 if quick else 400
    steps = data[torch.linspace(0, data.shape[0] - 1, min(n_masked, data.shape[0])).long()].select(*planner.in_keys)
    masked = _bench_masked(planner, steps)
    flops = _bench_flops(model, planner, level_t, quick)
    beam = _bench_beam21(fast, planner.in_keys, n_masked, quick)
    retime = _bench_retime(data, routes, fast, steps.shape[0])
    toy = _toy_planner_ms(repeats=20 if quick else 100)
    batch = _bench_batch64(model, steps, repeats=3 if quick else 10)
    return {**retime, "threads": torch.get_num_threads(), **exhaustive, **masked, **flops, **beam, **toy, **batch,
            "target": "level_vs_flat_ratio <= 0.3, masked_ms_median <= 20, retime_ms_median <= 20"}


def _bench_batch64(model, steps, repeats: int) -> dict[str, Any]:
    """(6) One masked search over a batch of 64 roots, on the CPU and, where there is one, on a CUDA device (the
    model and the roots moved there; the planner follows their device)."""



    roots = torch.cat([steps] * (64 // steps.shape[0] + 1))[:64].clone()
    out: dict[str, Any] = {"batch64_roots": 64}
    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    for device in devices:
        planner = TreeSearchPlanner(ImaginedNavigationEnv(make_world_model(copy.deepcopy(model).to(device))))
        batch = roots.to(device)
        planner(batch.clone())  # warm-up (and CUDA's kernels)

        def plan(planner=planner, batch=batch, device=device) -> None:
            planner(batch.clone())
            if device == "cuda":
                torch.cuda.synchronize()

        out[f"batch64_{device}_ms_median"] = _median_ms([_timed(plan)[0] for _ in range(repeats)])
    if "cuda" not in devices:
        out["batch64_cuda_ms_median"] = "no CUDA device"
    return out


def _bench_exhaustive(planner, data, quick: bool) -> tuple[dict[str, Any], list[float]]:
    """(1) The exhaustive level-by-level search vs a flat enumeration of the same tree, mask all-true."""
    def root(td):
        td = td.select(*planner.in_keys).clone()
        td["action_mask"] = torch.ones_like(td["action_mask"])
        return td.unsqueeze(0)

    picks = torch.linspace(0, data.shape[0] - 1, 3 if quick else 8).long()
    planner.search(root(data[0]))  # warm-up
    level_t, flat_t, same, evaluations = [], [], True, (0, 0)
    for i in picks.tolist():
        td = root(data[i])
        t_level, a = _timed(planner.search, td)
        t_flat, (b, flat_evaluations) = _timed(_flat_search, planner, td)
        level_t.append(t_level)
        flat_t.append(t_flat)
        same = same and torch.equal(a.actions[0], b)
        evaluations = (a.evaluations, flat_evaluations)
    ratio = statistics.median(level_t) / statistics.median(flat_t)
    return {"exhaustive_states": len(level_t), "exhaustive_level_ms_median": _median_ms(level_t),
            "exhaustive_flat_ms_median": _median_ms(flat_t), "level_vs_flat_ratio": round(ratio, 3),
            "level_vs_flat_same_actions": same, "model_evaluations_level_flat": list(evaluations)}, level_t


def _bench_masked(planner, steps) -> dict[str, Any]:
    """(2) The masked search (the planner as deployed) on recorded states."""
    planner(steps[0].clone())
    masked_t, masked_nodes = [], []
    for i in range(steps.shape[0]):
        masked_t.append(_timed(planner, steps[i].clone())[0])
        masked_nodes.append(planner.last.evaluations)
    return {"masked_states": len(masked_t), "masked_ms_median": _median_ms(masked_t),
            "masked_ms_p95": _p95_ms(masked_t), "masked_nodes_median": int(statistics.median(masked_nodes))}


def _bench_flops(model, planner, level_t: list[float], quick: bool) -> dict[str, Any]:
    """(3) The exhaustive search's achieved FLOP/s vs a bare matmul chain at the level batch sizes."""
    batches = [7 ** (h + 1) for h in range(planner.horizon)]
    flops = _mlp_flops(model) * sum(batches)
    t_search = statistics.median(level_t)
    t_chain = _matmul_chain_seconds(model, batches, repeats=3 if quick else 10)
    return {"exhaustive_gflops": round(flops / t_search / 1e9, 2),
            "matmul_chain_gflops": round(flops / t_chain / 1e9, 2),
            "flops_fraction_of_matmul": round(t_chain / t_search, 3)}


def _bench_beam21(fast: dict[str, Any], keys: list, n_masked: int, quick: bool) -> dict[str, Any]:
    """(4) 21 actions: the beam search (beam 64, masked) on states from a 21-action env."""


    data21 = _recorded_states({"Town1": [0]} if quick else {"Town1": [0, 1], "Town3": [0]},
                              {**fast, "adaptive_speed": True})
    model21 = DynamicsModel(n_actions=21)
    model21.fit_normalization(data21["history"], data21["action"], data21["next", "observation"])
    beam = TreeSearchPlanner(ImaginedNavigationEnv(make_world_model(model21)), beam=64)
    steps21 = data21[torch.linspace(0, data21.shape[0] - 1, min(n_masked // 2, data21.shape[0])).long()]
    steps21 = steps21.select(*keys)
    beam(steps21[0].clone())
    beam_t = [_timed(beam, steps21[i].clone())[0] for i in range(steps21.shape[0])]
    return {"beam21_width": 64, "beam21_states": len(beam_t), "beam21_ms_median": _median_ms(beam_t),
            "beam21_ms_p95": _p95_ms(beam_t)}


def _bench_retime(data, routes: dict[str, list[int]], fast: dict[str, Any], n_steps: int) -> dict[str, Any]:
    """(5) The default re-timing planner as the default study deploys it (horizon 12, an ensemble of the default
    preset's models, all members imagined at once) on states recorded with that preset's history length; and
    the same with the other road option."""
    train = preset("default").train
    data_k = data if train.K == 5 else _recorded_states(routes, fast, K=train.K)
    times: dict[int, list[float]] = {}
    for road in (train.road, 8 if train.road != 8 else 0):  # the default's model, and the other road option
        members = [DynamicsModel(K=train.K, hidden=train.hidden, road=road) for _ in range(train.ensemble)]
        for m in members:
            m.fit_normalization(data_k["history"], data_k["action"], data_k["next", "observation"], road_of(data_k))
        retime = RetimingPlanner(ImaginedNavigationEnv(make_world_model(members[0])))
        retime.params = [meta_parameters(m).detach() for m in members]
        times[road] = []
        for i in range(n_steps):
            before = retime.decisions
            t, _ = _timed(retime, data_k[i * data_k.shape[0] // n_steps].select(*retime.in_keys).clone())
            if retime.decisions > before:  # a decision with a choice (elsewhere it plays explore at once)
                times[road].append(t)
    retime_t, other = times[train.road], next(r for r in times if r != train.road)
    return {
        "retime_model": f"{train.ensemble} x MLP {list(train.hidden)}, K={train.K}",
        "retime_searched_states": len(retime_t),
        "retime_ms_median": _median_ms(retime_t) if retime_t else None,
        "retime_ms_p95": _p95_ms(retime_t) if retime_t else None,
        # the same planner with a model that reads the road (TrainConfig.road; or without it, if the default reads it)
        f"retime_road{other}_ms_median": _median_ms(times[other]) if times[other] else None,
    }


def _flat_search(planner, roots):
    """The reference for the level-by-level search: every sequence of the (all-true) tree of ``planner``
    (a :class:`~pernav.planner.TreeSearchPlanner`) rolled out on its own with the same model, scored with its
    reward terms; the best sequence and the model evaluations it took."""


    model, root = planner.model, roots[0]
    H = planner.levels(roots)
    seqs = torch.cartesian_prod(*[torch.arange(model.n_actions)] * H).reshape(-1, H)
    hist = root["history"].expand(seqs.shape[0], *root["history"].shape)
    ret = torch.zeros(seqs.shape[0])
    with torch.no_grad():
        for h in range(H):
            state = model(hist, seqs[:, h])
            ret -= tracking_cost(state[:, [X, Y]], hist[:, -1, [GX, GY]])  # vs the previous state's goal
            hist = model.next_window(hist, seqs[:, h], state)
        ret += planner.sequence_reward(roots, seqs.unsqueeze(0))[0]
    return seqs[int(ret.argmax())], seqs.numel()


def _toy_planner_ms(repeats: int) -> dict[str, Any]:
    """Decision time of the generic planner on a CartPole-sized learned model env (batch 1 and 16)."""


    torch.manual_seed(0)
    model = DynamicsModel(state_dim=4, n_actions=2, K=2, hidden=(64, 64))
    env = ImaginedEnv(model, reward_fn=lambda s, a, n: 1.0 - n[..., 0].abs(),
                      termination_fn=lambda n: n[..., 2].abs() > 0.21)
    planner = DiscreteTreeSearchPlanner(env, planning_horizon=8)
    out: dict[str, Any] = {"toy_env": "ImaginedEnv 4-d state, 2 actions, H=8, MLP [64, 64]"}
    for batch in (1, 16):
        roots = TensorDict({"observation": torch.randn(batch, 4) * 0.05, "history": torch.zeros(batch, 2, 6)}, [batch])
        planner(roots.clone())
        times = [_timed(planner, roots.clone())[0] for _ in range(repeats)]
        out[f"toy_batch{batch}_ms_median"] = _median_ms(times)
    return out


def _synthetic_transitions(shape: tuple[int, ...], n_actions: int = 7, K: int = 5, seed: int = 0):

    g = torch.Generator().manual_seed(seed)
    return TensorDict({"history": torch.randn(*shape, K, 14 + n_actions, generator=g),
                       "action": torch.randint(n_actions, shape, generator=g),
                       "observation": torch.randn(*shape, 14, generator=g),
                       ("next", "observation"): torch.randn(*shape, 14, generator=g)}, list(shape))


def bench_train(quick: bool = False, inner_windows: int | None = None) -> dict[str, Any]:
    """Time of one meta (FTML) update vs one plain (non-adaptive) update, paper sizes, same process.

    plain: L-step loss on a [128, 5] batch, backward, Adam step.
    meta:  U(P, tau) on one 120-step trajectory (second order: the adaptation step is differentiated),
           then the L-step loss of the adapted parameters on a [128, 5] batch, backward, Adam step.
           The first-order variant (adaptation gradient treated as a constant) is timed for reference.
    Timings do not depend on the data's values: the batches are synthetic.
    """


    torch.manual_seed(0)
    model = DynamicsModel()
    optim = torch.optim.Adam(model.parameters(), lr=1e-3)
    batch = _synthetic_transitions((128, 5))
    tau = _synthetic_transitions((120,), seed=1)

    def plain() -> None:
        optim.zero_grad()
        multistep_loss(model, batch).backward()
        optim.step()

    def meta(first_order: bool = False, stride: int | None = None) -> None:
        optim.zero_grad()
        adapted = adapt(model, tau, alpha=0.01, L=5, first_order=first_order, stride=stride)
        multistep_loss(model, batch, params=adapted).backward()
        optim.step()

    repeats = 3 if quick else 15
    plain(), meta(), meta(True)  # warm-up
    plain_t, meta_t, first_t, dense_t = [], [], [], []
    for _ in range(repeats):  # interleaved, so drifts in machine load hit all alike
        plain_t.append(_timed(plain)[0])
        meta_t.append(_timed(meta)[0])
        first_t.append(_timed(meta, True)[0])
        dense_t.append(_timed(meta, False, 1)[0])
    ratio = statistics.median(meta_t) / statistics.median(plain_t)
    return {
        "threads": torch.get_num_threads(),
        "batch_windows": 128,
        "L": 5,
        "tau_steps": 120,
        "plain_update_ms_median": _median_ms(plain_t),
        "meta_update_ms_median": _median_ms(meta_t),
        "meta_vs_plain_ratio": round(ratio, 2),
        "meta_first_order_update_ms_median": _median_ms(first_t),
        "meta_first_order_vs_plain_ratio": round(statistics.median(first_t) / statistics.median(plain_t), 2),
        "meta_every_window_update_ms_median": _median_ms(dense_t),
        "meta_every_window_vs_plain_ratio": round(statistics.median(dense_t) / statistics.median(plain_t), 2),
        "adaptation_windows": "tau tiled by L-windows (stride L, the default); every_window: stride 1",
        "target": "meta_vs_plain_ratio <= 3 (second order, the faithful default)",
    }


PLAY_VIEWS = (("top", "normal"), ("third_person", "normal"), ("first_person", "normal"), ("top", "foggy"),
              ("third_person", "foggy"), ("first_person", "foggy"))  # (camera, visual): each view, clear and in fog


def bench_play(quick: bool = False, screenshots: str | None = None, live: bool = False) -> dict[str, Any]:
    """Frame time of ``pernav play``'s loop (:class:`~pernav.play.loop.PlaySession`) in each view (camera ``top``,
    ``third_person``, ``first_person``, each clear and in fog) with the default traffic (8 cars), Town3 route 1 (a
    roundabout), the scripted bot at the wheel, drawn off screen (``SDL_VIDEODRIVER=dummy`` unless a display driver
    is set) as fast as it goes (not paced to the clock). A world frame's time is its compute (the world, and at each
    second's start the policy and the env's step) plus its pictures (30 per second over 10 world frames: 3 each); at
    10 world frames per second a frame must take under 100 ms for real time, and a picture under 33 ms for 30
    pictures per second. A picture's time is one draw of the view. The same drive without drawing is the reference.
    ``screenshots``: a folder to save one picture per view in (``view_<camera>[_fog].png``, 13 s into the drive, at the
    first junction, whose route turns left).

    ``live``: each view in a window paced to real time instead, the window's events handled, 30 s of the drive each
    (5 s if ``quick``): :func:`pernav.play.livebench.bench_live` (per view the frame time and how late each frame
    ended against the clock; the display used, ``dummy`` where there is no X11 or Wayland display)."""
    if live:

        return bench_live(PLAY_VIEWS, steps=5 if quick else 30, screenshots=screenshots)
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")

    steps = 15 if quick else 60
    out: dict[str, Any] = {"world_frames": 0, "pictures_per_world_frame": 3}
    for camera, visual in PLAY_VIEWS:
        name = camera if visual == "normal" else f"{camera}_fog"
        shot = None if screenshots is None else Path(screenshots) / f"view_{name}.png"
        session = PlaySession("Town3", 1, context={"camera": camera, "visual": visual},
                              options=PlayOptions(n_traffic=8, draw=True, realtime=False, screenshot=shot,
                                                  screenshot_at=13.0))
        pictures: list[float] = []
        draw = session.view.draw

        def timed_draw(*args: Any, _draw: Any = draw, _times: list[float] = pictures) -> None:
            t0 = time.perf_counter()
            _draw(*args)
            _times.append(time.perf_counter() - t0)

        session.view.draw = timed_draw
        d = session.run(max_steps=steps).frame_stats()
        out["world_frames"] = d["frames"]  # per view
        out[f"{name}_frame_ms_median"], out[f"{name}_frame_ms_p95"] = d["median_ms"], d["p95_ms"]
        out[f"{name}_picture_ms_median"], out[f"{name}_picture_ms_p95"] = _median_ms(pictures), _p95_ms(pictures)
        if session.shot is not None:
            out.setdefault("screenshots", []).append(str(session.shot))
    bare = PlaySession("Town3", 1, options=PlayOptions(n_traffic=8, draw=False, realtime=False))
    bare = bare.run(max_steps=steps).frame_stats()
    out["frame_without_drawing_ms_median"], out["frame_without_drawing_ms_p95"] = bare["median_ms"], bare["p95_ms"]
    # the slowest view's figures under the names this benchmark had before it had views
    names = [c if v == "normal" else f"{c}_fog" for c, v in PLAY_VIEWS]
    worst = max(names, key=lambda n: out[f"{n}_frame_ms_p95"])
    out.update(slowest_view=worst, frame_ms_median=out[f"{worst}_frame_ms_median"],
               frame_ms_p95=out[f"{worst}_frame_ms_p95"],
               drawn_vs_bare_median_ratio=round(out[f"{worst}_frame_ms_median"] / max(bare["median_ms"], 1e-9), 2))
    out["target"] = "every view's frame_ms_p95 <= 50 (a world frame with its 3 pictures)"
    return out


def bench_timing(quick: bool = False) -> dict[str, Any]:
    """Decision time of the timing learner (:mod:`pernav.learners.timing`): per step, explore's rule re-timed for a
    belief (the env computes it beside explore's own action, so the reference is explore's rule alone, same
    states); per round, the belief read from tau (features and the ridge prediction). The model is fitted on
    synthetic features (its decision time does not depend on what it learned)."""


    env = NavigationEnv("Town3", config={"n_traffic": 8})
    env.reset(seed=0, options={"route": 1, "user": "user3"})
    # a slow belief with the quick driver its guard keeps in mind (the learner's usual belief)
    rule = belief_policy({"reaction_time": 2.6, "decision_time": 3.0,
                          "fastest": {"reaction_time": 0.6, "decision_time": 1.5}})
    explore = explore_policy()
    belief_ms, explore_ms = [], []
    for _ in range(20 if quick else 80):
        view = env.nav_view()
        belief_ms.append(_timed(rule, view)[0])
        explore_ms.append(_timed(explore, view)[0])
        env.step(explore(view))
    g = torch.Generator().manual_seed(0)
    model = TimingModel().fit(torch.randn(64, N_FEATURES, generator=g), torch.rand(64, 2, generator=g) + 1.0)
    tau = drive(history_env("Town3", {"route": 1, "user": "user3"}, config={"n_traffic": 2}, seed=0, K=2),
                explore_module())
    round_ms = [_timed(model.belief, tau)[0] for _ in range(3 if quick else 10)]
    return {
        "decision_ms_median": _median_ms(belief_ms),
        "explore_rule_ms_median": _median_ms(explore_ms),
        "decision_vs_explore_ratio": round(_median_ms(belief_ms) / max(_median_ms(explore_ms), 1e-9), 2),
        "belief_from_tau_ms_median": _median_ms(round_ms),
        "tau_steps": int(tau.shape[0]),
        "target": "decision_ms_median <= 15",
    }


def bench_belief(quick: bool = False) -> dict[str, Any]:
    """The belief learner (:mod:`pernav.learners.belief`) inside a drive: per step, the tracker's update (reading each
    answer whose window closed and each announced junction's outcome; the step's work beside the world's frames) and
    the prompt decision of the rule re-timed for the belief it gives, against explore's rule on the same states. The
    belief is the joint one (reaction and decision time); the detectors are untrained (their cost does not depend on
    their weights)."""


    env = NavigationEnv("Town3", config={"n_traffic": 8})
    _, info = env.reset(seed=0, options={"route": 1, "user": "user3"})
    decision = DecisionPrior(mean=2.4, sd=0.7, hit=0.4, false=0.05)
    tracker = BeliefTracker(AnswerDetector(), ReactionBelief(0.3, 0.4, decision=decision), swerve=SwerveDetector())
    explore = explore_policy()
    update_ms, moved_ms, decision_ms, explore_ms = [], [], [], []
    for _ in range(60 if quick else 150):
        action = int(info["explore_action"])
        _, _, terminated, truncated, info = env.step(action)
        t0 = time.perf_counter()
        moved = tracker.observe(action, bool(info["played"]), info["prompt_end"], info["frames"], info["time"],
                                info["distance_to_junction"], info["missed_turns"])
        rule = belief_policy(tracker.fields()) if moved else None
        (moved_ms if moved else update_ms).append(time.perf_counter() - t0)
        view = env.nav_view()
        decision_ms.append(_timed(rule or belief_policy(tracker.fields()), view)[0])
        explore_ms.append(_timed(explore, view)[0])
        if terminated or truncated:
            break
    return {
        "update_ms_median": _median_ms(update_ms),
        "answer_read_ms_median": _median_ms(moved_ms) if moved_ms else None,
        "answers_read": tracker.belief.answers,
        "outcomes_read": tracker.belief.outcomes,
        "decision_ms_median": _median_ms(decision_ms),
        "decision_vs_explore_ratio": round(_median_ms(decision_ms) / max(_median_ms(explore_ms), 1e-9), 2),
        "target": "decision_ms_median <= 15, answer_read_ms_median <= 50",
    }


def bench_driver(quick: bool = False) -> dict[str, Any]:
    """adapt_driver's prompt decision (:class:`~pernav.learners.driver.DriverPlanner`) inside a drive: per step, its
    tracker's update on the step's frames and prompt, ``U`` on the drive so far where an answer arrived, and the
    re-timing tree search on the hybrid model (16 s, both ways, 10 rows), against explore's decision on the same
    states. The detectors are untrained and the meta model the population's (the cost does not depend on them)."""
    decision = DecisionPrior(mean=2.4, sd=0.7, hit=0.4, false=0.05)
    prior = DriverPrior.population((0.3, 0.4), (decision.mean, decision.sd), hit=decision.hit, false=decision.false)
    policy = DriverPlanner(DriverTracker(AnswerDetector(), DriverBelief(prior), SwerveDetector()), DRIVER_PLANNER)
    env = history_env("Town3", {"route": 1, "user": "user3"}, config={"n_traffic": 8}, seed=0, K=10)
    td = env.reset()
    decision_ms, searched_ms, explore_ms = [], [], []
    explore = explore_module()
    for _ in range(60 if quick else 150):
        before = policy.planner.decisions
        t0 = time.perf_counter()
        td = policy(td)
        (searched_ms if policy.planner.decisions > before else decision_ms).append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        explore(td.clone())
        explore_ms.append(time.perf_counter() - t0)
        td = env.step(td)
        if bool(td["next", "done"]):
            break
        td = td["next"]
    every = decision_ms + searched_ms
    return {
        "decision_ms_median": _median_ms(every),
        "searched_decision_ms_median": _median_ms(searched_ms) if searched_ms else None,
        "searches": len(searched_ms),
        "decision_vs_explore_ratio": round(_median_ms(every) / max(_median_ms(explore_ms), 1e-9), 2),
        "answers_read": len(policy.tracker.belief.evidence.answers),
        "target": "decision_ms_median <= 15",
    }


BENCHMARKS = {"sim": bench_sim, "planner": bench_planner, "train": bench_train, "play": bench_play,
              "timing": bench_timing, "belief": bench_belief, "driver": bench_driver}


def run_benchmarks(which: str = "all", quick: bool = False, screenshots: str | None = None,
                   live: bool = False) -> dict[str, dict[str, Any]]:
    """Run one benchmark (``sim``, ``planner``, ``train``, ``play``, ``timing``, ``belief``, ``driver``) or ``all``;
    returns
    {name: figures}.
    ``screenshots``: a folder for the play benchmark's picture of each view; ``live``: the play benchmark in a window
    paced to real time (:func:`bench_play`)."""
    if which != "all" and which not in BENCHMARKS:
        raise ValueError(f"unknown benchmark {which!r}; choose one of {', '.join(BENCHMARKS)} or all")
    names = list(BENCHMARKS) if which == "all" else [which]
    return {name: BENCHMARKS[name](quick=quick, **({"screenshots": screenshots, "live": live} if name == "play" else {}))
            for name in names}


def add_parser(sub: Any) -> None:
    """Register ``pernav bench``."""
    p = sub.add_parser("bench", help="benchmarks, as ratios measured in one run")
    p.add_argument("which", nargs="?", default="all", choices=[*BENCHMARKS, "all"])
    p.add_argument("--json", action="store_true")
    p.add_argument("--quick", action="store_true", help="shorter measurement (for smoke tests)")
    p.add_argument("--screenshots", metavar="DIR", help="with play: save a picture of each view in this folder")
    p.add_argument("--live", action="store_true", help="with play: drive each view in a real window paced to real "
                   "time (the display in DISPLAY, e.g. Xvfb; without one SDL's dummy driver, said so in the result)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    for option, given in (("--screenshots", args.screenshots is not None), ("--live", args.live)):
        if given and args.which != "play":
            raise UsageError(f"{option} goes with pernav bench play")
    if args.screenshots is not None and not Path(args.screenshots).is_dir():
        raise UsageError(f"--screenshots {args.screenshots!r}: no such folder")
    figures = run_benchmarks(args.which, quick=args.quick, screenshots=args.screenshots, live=args.live)
    if args.json:
        print(json.dumps(figures, indent=2))
    for name, fig in ({} if args.json else figures).items():
        print(f"[{name}]\n" + "\n".join(f"  {k}: {v}" for k, v in fig.items()))
