"""Does the model know the driver's timing? Prompt-now vs prompt-3-s-later divergence, true vs predicted.

At approach states of panel drivers' explore episodes (a prompt of explore's plan is due within 1-4 steps),
the true simulator is branched (re-seeded, 2 samples) into "explore's next prompts now" and "the same, 3 s
later", and the car's position divergence between the two after 5 and 10 steps is measured. Each model
imagines the same two sequences from the same state; the recipe reports the correlation (Pearson) between
the true and the predicted divergence, and the mean absolute error, for:

* ``meta``: adapt's final meta model from a study (``--study DIR``, its Town checkpoint);
* ``adapted``: that model after one adaptation step on one explore trajectory of the driver (as in the study);
* ``per-driver``: a model of the same size trained only on this driver's data (6 explore trajectories).

Run (after ``make study`` or ``pernav study --preset default --out runs/default``):
OMP_WAIT_POLICY=PASSIVE .venv/bin/python recipes/model_check.py --study runs/default [--town Town1]
[--json docs/figures/model_check/model_check.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from pernav.diagnostics import TrueDynamicsEnv
from pernav.diagnostics.panel import PANEL
from pernav.env.torchrl_env import explore_module
from pernav.model.adapt import adapt, meta_parameters
from pernav.model.dynamics import DynamicsModel
from pernav.model.world_model import ImaginedNavigationEnv, make_world_model
from pernav.trainer.buffers import RoundBuffers
from pernav.trainer.collect import drive, history_env
from pernav.trainer.ftml import FTMLTrainer, TrainConfig
from pernav.world.drivers import Context

DELAY, STEPS = 3, (5, 10)


def load_meta(study: Path, town: str) -> tuple[DynamicsModel, list]:
    """adapt's final meta model from a study's checkpoint: the module and every ensemble member's state."""
    manifest = json.loads((study / "checkpoints" / town / "manifest.json").read_text())
    state = torch.load(study / "checkpoints" / town / manifest["folder"] / "state.pt", weights_only=False)
    members = state["learners"]["adapt"]["members"]
    model = DynamicsModel(**members[0]["model_config"])
    return model, [member["model"] for member in members]


def driver_env(driver: str, town: str, route: int, seed: int, K: int):
    user, context = PANEL[driver]
    return history_env(town, {"route": route, "user": user, "context": Context(**context)},
                       config={"n_traffic": 4}, seed=seed, K=K)


def per_driver_model(driver: str, town: str, like: DynamicsModel) -> DynamicsModel:
    buffers = RoundBuffers(L=5, seed=0)
    for k in range(6):
        buffers.add(0, drive(driver_env(driver, town, k % 10, 500 + k, like.K), explore_module()), tau=(k == 0))
    model = DynamicsModel(**like.config())
    trainer = FTMLTrainer(model, buffers, TrainConfig(updates=50, batch=128, warm_updates=300), seed=0)
    trainer.fit_normalization()
    trainer.train(400, meta=False)
    return model


def approach_divergences(driver: str, town: str, models: dict, episodes: int = 2) -> dict[str, np.ndarray]:
    """``{name: [n_states, len(STEPS)]}`` position divergences (``true`` and each model's)."""
    out: dict[str, list] = {"true": [], **{k: [] for k in models}}
    for ep in range(episodes):
        env = driver_env(driver, town, ep, 900 + ep, next(iter(models.values()))[0].dynamics.K)
        td = env.reset()
        nav = env.base_env._env
        for _t in range(400):
            future = td["explore_future"]
            if bool(future[1:5].any()) and not bool(future[0]):
                now = future[int(future[1:5].nonzero()[0]) + 1:][: max(STEPS)]
                now = torch.cat([now, now[-1:].expand(max(STEPS) - now.shape[0])])
                later = torch.cat([torch.zeros(DELAY, dtype=now.dtype), now[: max(STEPS) - DELAY]])
                pair = torch.stack([now, later])
                pos, _ = TrueDynamicsEnv(nav, samples=2, seed=_t).imagine(td, pair)
                idx = [s - 1 for s in STEPS]
                out["true"].append((pos[:, 0] - pos[:, 1]).norm(dim=-1).mean(0)[idx].numpy())
                for name, (env_m, params) in models.items():
                    p, _ = env_m.imagine(td, pair, params=params)  # [M, 2, H, 2]: the members' mean
                    out[name].append((p[:, 0] - p[:, 1]).norm(dim=-1).mean(0)[idx].numpy())
            td = env.step(explore_module()(td))
            if bool(td["next", "done"]):
                break
            td = td["next"]
    return {k: np.array(v) for k, v in out.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--study", required=True, help="a study output folder with checkpoints")
    ap.add_argument("--town", default="Town1")
    ap.add_argument("--drivers", nargs="*", default=list(PANEL))
    ap.add_argument("--json", default="model_check.json")
    args = ap.parse_args()
    torch.set_num_threads(1)
    study = Path(args.study)
    if not (study / "checkpoints" / args.town / "manifest.json").is_file():
        print(f"error: no {args.town} checkpoint in {study} (run the study first)", file=sys.stderr)
        sys.exit(2)
    meta, members = load_meta(study, args.town)
    rows = {}
    for driver in args.drivers:
        tau = drive(driver_env(driver, args.town, 7, 77, meta.K), explore_module())
        params, adapted = [], []
        for state in members:  # U(P, tau) of every member, as the study adapts
            meta.load_state_dict(state)
            params.append(meta_parameters(meta).detach().clone())
            adapted.append(adapt(meta, tau, alpha=0.01, L=5, first_order=True).detach())
        own = per_driver_model(driver, args.town, meta)
        imagined = ImaginedNavigationEnv(make_world_model(meta))
        models = {"meta": (imagined, params), "adapted": (imagined, adapted),
                  "per-driver": (ImaginedNavigationEnv(make_world_model(own)), None)}
        div = approach_divergences(driver, args.town, models)
        rows[driver] = {"states": int(div["true"].shape[0]), "true_mean": div["true"].mean(0).round(2).tolist()}
        for name in models:
            corr = [float(np.corrcoef(div["true"][:, i], div[name][:, i])[0, 1]) for i in range(len(STEPS))]
            mae = np.abs(div["true"] - div[name]).mean(0)
            rows[driver][name] = {"corr": [round(c, 3) for c in corr], "mae": mae.round(2).tolist(),
                                  "pred_mean": div[name].mean(0).round(2).tolist()}
        print(driver, json.dumps(rows[driver]))
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps({"steps": STEPS, "delay_s": DELAY, "town": args.town, "drivers": rows},
                                          indent=1))
    print("| driver | states | true divergence m (5 s, 10 s) | corr meta | corr adapted | corr per-driver |")
    print("|---|---|---|---|---|---|")
    for d, r in rows.items():
        print(f"| {d} | {r['states']} | {r['true_mean']} | {r['meta']['corr']} | {r['adapted']['corr']} "
              f"| {r['per-driver']['corr']} |")


if __name__ == "__main__":
    main()
