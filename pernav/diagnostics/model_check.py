"""Does the model know the driver's timing? Prompt-now vs prompt-3-s-later divergence, true vs predicted.

A diagnostic of a finished study's models (docs/planning.md). Takes about 4 minutes per town on a 2-core laptop
CPU (measured on a ``smoke`` study; a default study's larger ensemble may take longer).

At approach states of panel drivers' explore episodes (a prompt of explore's plan is due within 1-4 steps),
the true simulator is branched (re-seeded, 2 samples) into "explore's next prompts now" and "the same, 3 s
later", and the car's position divergence between the two after 5 and 10 steps is measured. Each model
imagines the same two sequences from the same state; the diagnostic reports the correlation (Pearson) between
the true and the predicted divergence, and the mean absolute error, for:

* ``meta``: adapt's final meta model from a study (``--study DIR``, its Town checkpoint);
* ``adapted``: that model after one adaptation step on one trajectory of the driver (as in the study): an explore
  drive, or with ``--tau-policy retimed`` a drive with explore's prompts re-timed at random (the study's
  ``tau_policy`` option).
  The step is the study's own test-time ``U`` (its ``alpha``, ``L``, gradient clip and backtracking, from its
  study.json; a model with a context adapts only it); ``--adapt-step fixed``: the study's ``alpha`` as a fixed step,
  without clip or backtracking (how the model checks in docs/research/findings.md were made);
* ``personal``: the meta model fine-tuned as a study with personal updates adapts: ``--personal-updates`` (100)
  updates on that trajectory and ``--calibration`` (4) re-timed drives of the driver;
* ``per-driver``: a model of the same size trained only on this driver's data (6 explore trajectories).

Run (after ``make study`` or ``pernav study --preset default --out runs/default``; ``pernav diagnose model ...``
takes the same options):
OMP_WAIT_POLICY=PASSIVE .venv/bin/python -m pernav.diagnostics.model_check --study runs/default [--town Town1]
[--json runs/model_check/model_check_Town1.json] [--plot runs/model_check/divergence_Town1.png]
[--tau-policy retimed --calibration 0 --personal-updates 100]  (the models of a study run with those options)
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import torch
from tensordict import TensorDictBase
from torchrl.envs import EnvBase

from pernav.diagnostics import TrueDynamicsEnv
from pernav.diagnostics.panel import PANEL
from pernav.env.torchrl_env import explore_module, navigation_of
from pernav.model.adapt import adapt, meta_parameters
from pernav.model.driver import DriverImaginedEnv
from pernav.model.dynamics import DynamicsModel
from pernav.model.navigation import ImaginedNavigationEnv, make_world_model
from pernav.planner.factory import env_planning_config
from pernav.planner.retiming import RetimedExplore
from pernav.study.finished import FinishedStudy, StudyError
from pernav.trainer.buffers import RoundBuffers
from pernav.trainer.collect import drive, history_env
from pernav.trainer.ensemble import EnsembleTrainer
from pernav.trainer.ftml import FTMLTrainer, TrainConfig
from pernav.world.drivers import Context

DELAY, STEPS = 3, (5, 10)
PLANNING = env_planning_config({"kind": "retime"})  # the explore plan as far ahead as the re-timings reach
TAU_ROUTE = 7  # the route of tau, the drive every model adapts on (seed 77): never a scored state's


def driver_env(driver: str, town: str, route: int, seed: int, K: int, config: dict | None = None) -> EnvBase:
    """The panel ``driver``'s history env (4 traffic cars) on ``route`` of ``town``; ``config`` adds env options."""
    user, context = PANEL[driver]
    return history_env(town, {"route": route, "user": user, "context": Context(**context)},
                       config={"n_traffic": 4, **(config or {})}, seed=seed, K=K)


def personal_params(meta: DynamicsModel, members: list, tau: TensorDictBase, driver: str, town: str,
                    calibration: int = 4, updates: int = 100) -> list:
    """The members fine-tuned as a study with ``calibration`` and ``personal_updates`` adapts: ``updates``
    updates on ``tau`` and ``calibration`` re-timed drives of the driver."""
    drives = [drive(driver_env(driver, town, k, 780 + k, meta.K, PLANNING), RetimedExplore(seed=780 + k))
              for k in range(calibration)]
    train = TrainConfig(L=5, batch=128).for_model(meta.config())
    return EnsembleTrainer.from_states(meta.config(), members, train).fine_tuned([tau, *drives], updates, seed=0)


def per_driver_model(driver: str, town: str, like: DynamicsModel) -> DynamicsModel:
    """A model of ``like``'s size trained (not meta-trained) on 6 explore drives of ``driver`` only."""
    buffers = RoundBuffers(L=5, seed=0)
    for k in range(6):
        buffers.add(0, drive(driver_env(driver, town, k % 10, 500 + k, like.K), explore_module()), tau=(k == 0))
    model = DynamicsModel(**like.config())
    trainer = FTMLTrainer(model, buffers, TrainConfig(updates=50, batch=128, warm_updates=300).for_model(like.config()),
                          seed=0)
    trainer.fit_normalization()
    trainer.train(400, meta=False)
    return model


def approach_pairs(driver: str, town: str, episodes: int = 2, K: int = 10, first: int = 0
                   ) -> Iterator[tuple[TensorDictBase, Any, int, torch.Tensor]]:
    """The diagnostic's approach states of the panel ``driver`` (explore's episodes ``first ...``, route ``ep`` with
    seed ``900 + ep``; the diagnostic's own are ``first=0``, a structure check's held-out ones later): at each step
    where a prompt of explore's plan is due within 1-4 steps, ``(root, live navigation env, step, pair)``, ``pair``
    ``[2, max(STEPS)]`` the plan's next prompts now and the same :data:`DELAY` s later."""
    for ep in range(first, first + episodes):
        env = driver_env(driver, town, ep, 900 + ep, K)
        td = env.reset()
        nav = navigation_of(env)
        for t in range(400):
            future = td["explore_future"]
            if bool(future[1:5].any()) and not bool(future[0]):
                now = future[int(future[1:5].nonzero()[0]) + 1:][: max(STEPS)]
                now = torch.cat([now, now[-1:].expand(max(STEPS) - now.shape[0])])
                later = torch.cat([torch.zeros(DELAY, dtype=now.dtype), now[: max(STEPS) - DELAY]])
                yield td, nav, t, torch.stack([now, later])
            td = env.step(explore_module()(td))
            if bool(td["next", "done"]):
                break
            td = td["next"]


def divergence(pos: torch.Tensor) -> np.ndarray:
    """``[len(STEPS)]``: the distance between a pair's two imagined positions ``[M, 2, H, 2]`` after each of
    :data:`STEPS`, averaged over the rows (members, samples or quantiles)."""
    return (pos[:, 0] - pos[:, 1]).norm(dim=-1).mean(0)[[s - 1 for s in STEPS]].numpy()


def approach_divergences(driver: str, town: str, models: dict, episodes: int = 2, K: int = 10, ceiling: int = 0,
                         first: int = 0) -> dict[str, np.ndarray]:
    """``{name: [n_states, len(STEPS)]}`` position divergences (``true`` and each model's; a model is an env with
    ``imagine`` and its parameters, ``None``: its own), from the history env of window ``K`` at
    :func:`approach_pairs`'s states (``first``: its first episode); with ``ceiling``, also the true simulator's mean
    over that many fresh samples (``"ceiling"``)."""
    out: dict[str, list] = {"true": [], **({"ceiling": []} if ceiling else {}), **{k: [] for k in models}}
    for td, nav, t, pair in approach_pairs(driver, town, episodes, K, first):
        out["true"].append(divergence(TrueDynamicsEnv(nav, samples=2, seed=t).imagine(td, pair)[0]))
        if ceiling:  # the simulator's own mean over ``ceiling`` fresh samples: what r can reach
            out["ceiling"].append(divergence(TrueDynamicsEnv(nav, samples=ceiling, seed=10_000 + t).imagine(td, pair)[0]))
        for name, (env_m, params) in models.items():
            p, _ = (env_m.imagine(td, pair, params=params) if params is not None else env_m.imagine(td, pair))
            out[name].append(divergence(p))
    return {k: np.array(v) for k, v in out.items()}


def _adapt_models(study: Any, tau: TensorDictBase, driver: str, args: argparse.Namespace) -> dict[str, tuple]:
    """adapt's models for ``driver``: the meta model, ``U(P, tau)`` as the study adapts, the personal and the
    per-driver models."""
    meta, members, train = DynamicsModel(**study.model_config), study.members, study.train
    step = {"alpha": train.alpha, "L": train.L, "max_norm": None}  # fixed: the step unclipped
    if args.adapt_step == "study":
        step.update(max_norm=train.max_grad_norm, backtrack=train.backtrack)
    params, adapted = [], []
    for state in members:  # U(P, tau) of every member, as the study adapts
        meta.load_state_dict(state)
        params.append(meta_parameters(meta).detach().clone())
        # clone: with a context U replaces only it, and the rest aliases meta's tensors, which the next
        # member's load_state_dict overwrites in place
        adapted.append(adapt(meta, tau, first_order=True, **step).detach().clone())
    own = per_driver_model(driver, args.town, meta)
    imagined = ImaginedNavigationEnv(make_world_model(meta))
    return {"meta": (imagined, params), "adapted": (imagined, adapted),
            "personal": (imagined, personal_params(meta, members, tau, driver, args.town, args.calibration,
                                                   args.personal_updates)),
            "per-driver": (ImaginedNavigationEnv(make_world_model(own)), None)}


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """The command line (``argv``: its arguments, default ``sys.argv[1:]``); the exit code (2: no checkpoint)."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n")[0])
    ap.add_argument("--study", required=True, help="a study output folder with checkpoints")
    ap.add_argument("--town", default="Town1")
    ap.add_argument("--drivers", nargs="*", default=list(PANEL))
    ap.add_argument("--json", default="model_check.json")
    ap.add_argument("--plot", default=None, help="scatter of true vs predicted divergence (png)")
    ap.add_argument("--tau-policy", dest="tau_policy", choices=["explore", "retimed"], default="explore",
                    help="the adaptation trajectory's policy, as the study's tau_policy option (default explore)")
    ap.add_argument("--calibration", type=int, default=4, help="re-timed drives of the personal model (default 4)")
    ap.add_argument("--personal-updates", type=int, default=100, help="updates of the personal model (default 100)")
    ap.add_argument("--ceiling", type=int, default=0, help="also the true simulator's mean over this many fresh "
                    "samples against the same truth: the r a perfect model of the expectation reaches (default 0: not "
                    "measured; 20 takes about 10x the diagnostic's time)")
    ap.add_argument("--adapt-step", choices=["study", "fixed"], default="study",
                    help="U as the study adapts at test time (default), or its fixed step alpha unclipped")
    ap.add_argument("--first-episode", dest="first_episode", type=int, default=0,
                    help="the panel's first episode whose states are scored (default 0: the diagnostic's own, "
                         "episodes 0-1, on which the models were developed; 2: held-out states, episodes 2-3)")
    args = ap.parse_args(argv)
    if args.first_episode < 0 or args.first_episode <= TAU_ROUTE < args.first_episode + 2:
        ap.error(f"--first-episode must be >= 0, and its two episodes must not include tau's route "
                 f"({TAU_ROUTE}); got {args.first_episode}")
    torch.set_num_threads(1)
    try:  # the finished study's adapt ensemble and the settings it adapted with; adapt_driver's state
        finished = FinishedStudy.open(args.study)
        study = finished.model(args.town, "adapt") if "adapt" in finished.model_learners else None
        driver_state = finished.driver_state(args.town) if "adapt_driver" in finished.methods else None
        if study is None and driver_state is None:
            raise StudyError(f"the study in {args.study!r} ran neither adapt nor adapt_driver")
    except StudyError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    K = finished.history(args.town)
    rows, pooled = {}, {}
    for driver in args.drivers:
        retimed = args.tau_policy == "retimed"
        policy = RetimedExplore(seed=77) if retimed else explore_module()
        tau = drive(driver_env(driver, args.town, TAU_ROUTE, 77, K, PLANNING if retimed else None), policy)
        models = _adapt_models(study, tau, driver, args) if study is not None else {}
        if driver_state is not None:  # the hybrid model: U(P, tau) and, without adaptation, P's centre
            trackers = driver_state.read_tau(driver, "diagnosis", tau, ["adapt_driver", "adapt_driver_static"])
            models["adapt_driver"] = (DriverImaginedEnv(trackers["adapt_driver"].belief.drivers()), None)
            models["adapt_driver_meta"] = (DriverImaginedEnv(trackers["adapt_driver_static"].belief.drivers()), None)
        div = approach_divergences(driver, args.town, models, K=K, ceiling=args.ceiling, first=args.first_episode)
        for name, values in div.items():
            pooled.setdefault(name, []).append(values)
        rows[driver] = {"states": int(div["true"].shape[0]), "true_mean": [round(float(x), 2) for x in div["true"].mean(0)]}
        for name in [k for k in div if k != "true"]:
            corr = [float(np.corrcoef(div["true"][:, i], div[name][:, i])[0, 1]) for i in range(len(STEPS))]
            mae = np.abs(div["true"] - div[name]).mean(0)
            rows[driver][name] = {"corr": [round(c, 3) for c in corr], "mae": [round(float(x), 2) for x in mae],
                                  "pred_mean": [round(float(x), 2) for x in div[name].mean(0)]}
        print(driver, json.dumps(rows[driver]))
    pooled = {k: np.concatenate(v) for k, v in pooled.items()}
    overall = {name: [round(float(np.corrcoef(pooled["true"][:, i], pooled[name][:, i])[0, 1]), 3)
                      for i in range(len(STEPS))] for name in pooled if name != "true"}
    small = pooled["true"] < 0.5  # where the truth says the timing changes nothing: is the prediction under 1 m?
    quiet = {name: [round(float((pooled[name][:, i][small[:, i]] < 1.0).mean()), 3) if small[:, i].any() else None
                    for i in range(len(STEPS))] for name in pooled if name != "true"}
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps({"steps": STEPS, "delay_s": DELAY, "town": args.town,
                                           "first_episode": args.first_episode, "drivers": rows,
                                           "pooled_corr": overall, "under_1m_where_true_under_0_5m": quiet,
                                           "divergences": {k: v.round(2).tolist() for k, v in pooled.items()}},
                                          indent=1))
    if args.plot:
        scatter(pooled, args.plot, args.town)
    names = [k for k in overall]
    print("| driver | states | true divergence m (5 s, 10 s) | " + " | ".join(f"corr {n}" for n in names) + " |")
    print("|---|---|---|" + "---|" * len(names))
    for d, r in rows.items():
        print(f"| {d} | {r['states']} | {r['true_mean']} | " + " | ".join(str(r[n]["corr"]) for n in names) + " |")
    print(f"| all drivers | {pooled['true'].shape[0]} | {[round(float(x), 2) for x in pooled['true'].mean(0)]} | "
          + " | ".join(str(overall[n]) for n in names) + " |")
    return 0


def scatter(pooled: dict[str, np.ndarray], path: str, town: str) -> None:
    """True vs predicted divergence after 10 steps, one panel per model, every driver's states pooled."""
    matplotlib.use("Agg")  # headless
    names = [k for k in pooled if k != "true"]
    fig, axes = plt.subplots(1, len(names), figsize=(4 * len(names), 4), sharex=True, sharey=True)
    top = max(float(v[:, -1].max()) for v in pooled.values()) * 1.05
    for ax, name in zip(axes, names, strict=True):
        ax.scatter(pooled["true"][:, -1], pooled[name][:, -1], s=10, alpha=0.6)
        ax.plot([0, top], [0, top], color="grey", lw=1)
        r = np.corrcoef(pooled["true"][:, -1], pooled[name][:, -1])[0, 1]
        ax.set_title(f"{name}: r = {r:.2f}")
        ax.set_xlabel(f"true divergence after {STEPS[-1]} s (m)")
    axes[0].set_ylabel("predicted divergence (m)")
    fig.suptitle(f"prompt now vs {DELAY} s later, {town}: does the model know the driver's timing?")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)


if __name__ == "__main__":
    sys.exit(main())
