"""How much of *this* driver's data does the learned model need before planning on it pays?

The end-to-end study adapts a meta model with one gradient step on one explore trajectory, and its planner
stays on explore (docs/research/findings.md, world v1). This recipe asks the question underneath: with N of the driver's own
trajectories (explore with its prompts re-timed at random, :class:`pernav.planner.RetimedExplore`, the study's
``collect: retimed`` data), does an ensemble trained only on them (the study's size: 3 × [128, 128], K = 10)
let the default planner beat explore for that driver? If it does for some N, the model class can learn a
driver's timing and the gap is data/adaptation; if it does not even for large N, the model class (or the
confidence gate) is what loses.

For every panel driver (:data:`pernav.diagnostics.panel.PANEL`) and town: N trajectories on routes k mod 10
(seeds derived from ``--seed``, never the evaluation seeds), an ensemble per N in ``--sizes`` (nested data:
the first N), then the paired evaluation episodes of ``pernav/diagnostics/planning_error.py`` (route r, seed 1000 + r)
with ``explore``, ``oracle`` and ``retime@own<N>`` (the default planner on that ensemble). Results are written
as (driver, town) jobs finish; ``--resume`` keeps finished jobs.

Run: OMP_WAIT_POLICY=PASSIVE .venv/bin/python docs/research/scripts/driver_data.py [--sizes 4 16 64] [--routes 5]
[--updates 600] [--workers 2] [--drivers LABEL ...] [--json FILE] [--resume]
[--init STUDY]  (fine-tune the study's final adapt ensemble on the driver's data instead: size 0 is that ensemble)
[--planner-option KEY=VALUE ...] (the planner's gate, e.g. max_spread=null) [--bootstrap] (each member fits its own
bootstrap resample of the driver's data, :meth:`EnsembleTrainer.fine_tuned`) [--tag NAME] (appended to the method)

The gate probe of docs/research/findings.md ("Which gate?"): a finished calibration study's ensemble, 4 own drives, 100
updates, per gate: ``--init runs/hr0 --sizes 4 --updates 100 --routes 5 [--planner-option max_spread=null] [--bootstrap]``.
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import torch
from tqdm import tqdm

from pernav.diagnostics.panel import PANEL, PanelJob, comparison_table, drive_panel_episode
from pernav.env.layout import STATE_DIM
from pernav.model.adapt import meta_parameters
from pernav.model.dynamics import DynamicsModel
from pernav.planner.factory import env_planning_config, parse_planner_options
from pernav.planner.retiming import RetimedExplore
from pernav.study.checkpoints import final_models
from pernav.trainer.buffers import RoundBuffers
from pernav.trainer.collect import derive_seed, drive, history_env
from pernav.trainer.ensemble import EnsembleTrainer
from pernav.trainer.ftml import TrainConfig
from pernav.world.drivers import Context

TOWNS = ("Town1", "Town3")
TRAIN = TrainConfig(batch=128, hidden=[128, 128], K=10, ensemble=3)  # the default study's model


def driver_trajectories(driver: str, town: str, n: int, seed: int) -> list:
    """``n`` re-timed explore trajectories of ``driver`` in ``town`` (routes k mod 10)."""
    user, context = PANEL[driver]
    config = {"n_traffic": 4, **env_planning_config({"kind": "retime"})}
    out = []
    for k in range(n):
        env = history_env(town, {"route": k % 10, "user": user, "context": Context(**context)}, config=config,
                          seed=derive_seed(seed, driver, town, k), K=TRAIN.K)
        out.append(drive(env, RetimedExplore(seed=derive_seed(seed, "retimed", driver, town, k))))
    return out


def own_ensemble(trajectories: list, updates: int, seed: int, init: list[dict] | None = None,
                 bootstrap: bool = False, config: dict[str, Any] | None = None) -> tuple[dict[str, Any], list]:
    """An ensemble trained (plain maximum likelihood) on ``trajectories`` only: (model spec, member params).

    ``init``: the members' starting state dicts (a study's meta model, normalization included) instead of a
    random initialization with normalization fitted on the data (:meth:`EnsembleTrainer.fine_tuned`; no
    trajectories: that ensemble unchanged); ``bootstrap``: each member fine-tunes on its own resample; ``config``:
    the members' architecture (``init``'s, e.g. a study's model that reads the road; default: the default preset's)."""
    config = config or {"state_dim": STATE_DIM, "n_actions": 7, "K": TRAIN.K, "hidden": TRAIN.hidden}
    train = TRAIN.for_model(config)  # the study's model may differ from the default preset's
    if init is None:
        trainer = EnsembleTrainer(lambda: DynamicsModel(**config), RoundBuffers.of(trajectories, train.L, seed),
                                  train, size=train.ensemble, seed=seed)
        trainer.fit_normalization()
        trainer.train(updates, meta=False)
        params = [meta_parameters(m.model).detach().clone() for m in trainer.members]
    else:
        trainer = EnsembleTrainer.from_states(config, init, train, seed=seed)
        params = (trainer.fine_tuned(trajectories, updates, seed, bootstrap=bootstrap) if trajectories
                  else [meta_parameters(m.model).detach().clone() for m in trainer.members])
    model = trainer.model
    return {"config": model.config(), "state": {k: v.clone() for k, v in model.state_dict().items()}}, params


def run_job(driver: str, town: str, sizes: list[int], routes: int, updates: int, seed: int,
            study: str | None = None, planner: dict | None = None, bootstrap: bool = False, tag: str = "") -> list[dict]:
    """Every episode of one (driver, town): explore, oracle and the planner on each size's own ensemble
    (fine-tuned from ``study``'s final adapt ensemble when given; size 0: that ensemble unchanged)."""
    torch.set_num_threads(1)
    study_model, init = final_models(study, town) if study else (None, None)
    label = "meta+own" if study else "own"
    t0 = time.perf_counter()
    data = driver_trajectories(driver, town, max(sizes), seed)
    sizes = [0, *sizes] if study else sizes
    episodes = [drive_panel_episode(PanelJob(driver, town, r, 1000 + r, m)) for r in range(routes)
                for m in ("explore", "oracle")]
    for n in sizes:
        spec, params = own_ensemble(data[:n], updates, derive_seed(seed, driver, town, "init"), init, bootstrap,
                                    study_model.config() if study_model else None)
        for r in range(routes):
            e = drive_panel_episode(PanelJob(driver, town, r, 1000 + r, "retime@learned", planner=planner or {},
                                             model=spec, params=params))
            e.update(method=f"retime@{label}{n}{tag}", trajectories=n,
                     transitions=sum(int(t.shape[0]) for t in data[:n]))
            episodes.append(e)
    for e in episodes:
        e["job_s"] = round(time.perf_counter() - t0, 1)
    return episodes


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[4, 16, 64], help="own trajectories per model")
    ap.add_argument("--routes", type=int, default=5, help="evaluation routes 0..N-1 of each town")
    ap.add_argument("--updates", type=int, default=600, help="training updates per ensemble")
    ap.add_argument("--drivers", nargs="*", default=list(PANEL))
    ap.add_argument("--towns", nargs="*", default=list(TOWNS))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", default="docs/figures/driver_data/driver_data.json")
    ap.add_argument("--resume", action="store_true", help="keep the (driver, town) jobs already in --json")
    ap.add_argument("--init", default=None, metavar="STUDY",
                    help="fine-tune a finished study's final adapt ensemble instead of training from scratch")
    ap.add_argument("--planner-option", action="append", default=[], metavar="KEY=VALUE",
                    help="a retime planner option (JSON value, e.g. max_spread=null); repeatable")
    ap.add_argument("--bootstrap", action="store_true", help="each member fine-tunes on its own bootstrap resample")
    ap.add_argument("--tag", default="", help="appended to the planner's method name (tell variants apart)")
    args = ap.parse_args()
    if args.bootstrap and not args.init:
        ap.error("--bootstrap resamples the drives a study's ensemble is fine-tuned on: it needs --init STUDY")
    try:
        planner = parse_planner_options("retime", args.planner_option)
    except ValueError as exc:
        ap.error(f"--planner-option {exc}")
    if args.init and not all((Path(args.init) / "checkpoints" / t / "manifest.json").is_file() for t in args.towns):
        ap.error(f"--init {args.init}: no checkpoint for every town of {args.towns} (run the study first)")
    unknown = [d for d in args.drivers if d not in PANEL]
    if unknown or min(args.sizes) < 1 or not 1 <= args.routes <= 10:
        ap.error(f"drivers must be panel labels ({', '.join(PANEL)}), sizes >= 1, routes in [1, 10]"
                 f"{f'; unknown driver {unknown[0]!r}' if unknown else ''}")
    episodes: list[dict] = []
    if args.resume and Path(args.json).is_file():
        episodes = json.loads(Path(args.json).read_text())["episodes"]
    done = {(e["driver"], e["town"]) for e in episodes}
    jobs = [(d, t) for d in args.drivers for t in args.towns if (d, t) not in done]
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    with ProcessPoolExecutor(args.workers) as pool:
        futures = [pool.submit(run_job, d, t, args.sizes, args.routes, args.updates, args.seed, args.init, planner,
                               args.bootstrap, args.tag) for d, t in jobs]
        for f in tqdm(as_completed(futures), total=len(futures), desc="driver x town"):
            episodes.extend(f.result())
            Path(args.json).write_text(json.dumps({
                "sizes": args.sizes, "updates": args.updates, "seed": args.seed, "init": args.init,
                "planner": planner, "bootstrap": args.bootstrap,
                "drivers": {d: PANEL[d] for d in args.drivers}, "episodes": episodes}, indent=1))
    print(comparison_table(episodes))
    for town in args.towns:
        print(f"\n{town}")
        print(comparison_table([e for e in episodes if e["town"] == town]))


if __name__ == "__main__":
    main()
