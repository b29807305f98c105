"""The online study: towns in parallel, results.json (SPEC.md §7), report and figures.

Example (the smoke preset, ~1 minute):
    >>> from pernav.study import preset, run_study
    >>> results = run_study(preset("smoke"), "/tmp/pernav-smoke")      # doctest: +SKIP
    >>> sorted(results)                                                 # doctest: +SKIP
    ['config', 'iterations', 'regret', 'summary', 'timing']
"""

from __future__ import annotations

import json
import logging
import multiprocessing
import os
import statistics
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import MISSING, fields
from pathlib import Path
from typing import Any

from pernav.study.compare import compare
from pernav.study.config import METHODS, StudyConfig
from pernav.study.parallel import init_worker, make_executor
from pernav.study.report import running_mean, write_report
from pernav.study.runner import run_town
from pernav.trainer.ftml import TrainConfig

__all__ = ["OutputError", "check_output", "run_study", "summarize"]

TIMING_KEYS = ("timing",)


class OutputError(ValueError):
    """The output folder cannot be used (it holds a different study, or a study without --resume)."""


def _fingerprint(cfg: StudyConfig) -> dict[str, Any]:
    return json.loads(json.dumps(cfg.to_dict()))


def _option_defaults() -> dict[str, Any]:
    """The fingerprint's default of every option that has one (the study options and ``train``)."""
    out = {f.name: f.default if f.default_factory is MISSING else f.default_factory()
           for f in fields(StudyConfig) if f.default is not MISSING or f.default_factory is not MISSING}
    out["train"] = TrainConfig().to_dict()
    return json.loads(json.dumps(out))


def _difference(saved: dict[str, Any], current: dict[str, Any], defaults: dict[str, Any],
                prefix: str = "") -> str | None:
    """The first option (dotted) where two fingerprints differ, or None. An option the saved study lacks
    predates that option, so the study ran with its default: it matches a current value equal to the default."""
    for key in [*current, *(k for k in saved if k not in current)]:
        if key not in saved:
            if key in defaults and current[key] == defaults[key]:
                continue
            return prefix + key
        if key not in current:
            return prefix + key
        if isinstance(saved[key], dict) and isinstance(current[key], dict) and isinstance(defaults.get(key), dict):
            inner = _difference(saved[key], current[key], defaults[key], f"{prefix}{key}.")
            if inner:
                return inner
        elif saved[key] != current[key]:
            return prefix + key
    return None


def check_output(cfg: StudyConfig, out: Path, resume: bool) -> None:
    """Refuse to overwrite: a folder with a study in it needs ``--resume`` and the same configuration."""
    marker = out / "study.json"
    if out.exists() and not out.is_dir():
        raise OutputError(f"output {str(out)!r} exists and is not a folder")
    if marker.exists():
        if not resume:
            raise OutputError(f"output folder {str(out)!r} already holds a study; pass --resume to continue it "
                              "or choose another --out")
        try:
            saved = json.loads(marker.read_text())
        except json.JSONDecodeError:
            raise OutputError(f"{str(marker)!r} is corrupted; cannot tell which study this folder holds") from None
        diff = _difference(saved, _fingerprint(cfg), _option_defaults()) if isinstance(saved, dict) else "config"
        if diff:
            raise OutputError(f"output folder {str(out)!r} holds a different study (its {diff!r} differs); "
                              "choose another --out")
    elif out.exists() and any(out.iterdir()):
        raise OutputError(f"output folder {str(out)!r} is not empty and holds no pernav study; choose another --out")


def _town_job(args: tuple[StudyConfig, str, str, bool, int, str]) -> dict[str, Any]:
    cfg, town, out, resume, position, episodes = args
    executor = make_executor(ray=True) if episodes == "ray" else None
    return run_town(cfg, town, out, resume=resume, position=position, executor=executor)


def run_study(cfg: StudyConfig, out: str | Path, resume: bool = False, workers: int = 1,
              report: bool = True, ray: bool = False, ray_address: str | None = None) -> dict[str, Any]:
    """Run every town, then write results.json, report.md and figures/.

    ``workers > 1``: towns run in parallel processes (or, with fewer towns than workers, one town at a time
    with its evaluation episodes in parallel). ``ray``: towns and evaluation episodes are Ray tasks on the
    cluster at ``ray_address`` (a local one with ``workers`` CPUs when None). Results do not depend on
    where the work ran.
    """
    cfg.validate()
    out = Path(out)
    check_output(cfg, out, resume)
    out.mkdir(parents=True, exist_ok=True)
    (out / "study.json").write_text(json.dumps(_fingerprint(cfg), indent=1))
    t0 = time.perf_counter()
    if ray:
        towns = _run_on_ray(cfg, out, resume, workers, ray_address)
    elif workers > 1 and len(cfg.towns) >= workers:
        jobs = [(cfg, town, str(out), resume, i, "serial") for i, town in enumerate(cfg.towns)]
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=init_worker) as pool:
            towns = list(pool.map(_town_job, jobs))
    else:
        executor = make_executor(workers)
        try:
            towns = [run_town(cfg, town, out, resume=resume, executor=executor) for town in cfg.towns]
        finally:
            executor.close()
    results = assemble(cfg, towns)
    results["timing"] = {"wall_s": round(time.perf_counter() - t0, 1), "workers": workers, "ray": ray,
                         "towns": {t["town"]: t["timing"] for t in towns},
                         "profile": {t["town"]: t["profile"] for t in towns}}
    tmp = out / ".results.json.tmp"
    tmp.write_text(json.dumps(results, indent=1))
    os.replace(tmp, out / "results.json")
    if report:
        write_report(results, out)
    return results


def _run_on_ray(cfg: StudyConfig, out: Path, resume: bool, workers: int, address: str | None) -> list[dict[str, Any]]:
    try:
        import ray
    except ImportError:
        raise OutputError("--ray needs Ray: pip install 'pernav[ray]'") from None
    started = not ray.is_initialized()
    if started:
        kwargs = {"address": address} if address else {"num_cpus": max(workers, 1)}
        ray.init(include_dashboard=False, logging_level=logging.WARNING, log_to_driver=False, **kwargs)
    try:
        task = ray.remote(num_cpus=1)(_town_job)
        refs = [task.remote((cfg, town, str(out), resume, i, "ray")) for i, town in enumerate(cfg.towns)]
        return ray.get(refs)
    finally:
        if started:
            ray.shutdown()


def assemble(cfg: StudyConfig, towns: list[dict[str, Any]]) -> dict[str, Any]:
    """results.json: config, iterations (entry -> town -> method -> figures), summary, regret."""
    by_town = {t["town"]: {r["label"]: r for r in t["results"]} for t in towns}
    iterations = []
    for entry in cfg.schedule:
        item = {"label": entry.label, "phase": entry.phase, "user": entry.user(), "towns": {}}
        for town, records in by_town.items():
            if entry.label in records:
                item["towns"][town] = records[entry.label]["methods"]
        iterations.append(item)
    regret = {}
    for t in towns:
        online = t["online_losses"]
        hind = t["hindsight_losses"]
        costs = []
        for r in t["results"]:
            m = r["methods"]
            if r["phase"] == "online" and "adapt" in m and "hindsight" in m:
                costs.append(m["adapt"]["tracking_cost"] - m["hindsight"]["tracking_cost"])
        losses = [online[k] - hind[k] for k in online if k in hind]
        regret[t["town"]] = {
            "labels": [k for k in online if k in hind],
            "loss_regret": losses,  # l_t(U(P_t, tau_t)) - l_t(U(P_hindsight, tau_t)) on D_t
            "average_loss_regret": running_mean(losses),
            "cost_regret": costs,  # adapt - hindsight episodic cost per round
            "average_cost_regret": running_mean(costs),
            # does one-shot adaptation help? L-step loss of adapt's model on D_t without / with U(P_t, tau_t)
            # (and with the paper's fixed step where U backtracks: "adapted_fixed_step")
            "adaptation": {k: {"unadapted": t["unadapted_losses"].get(k), "adapted": online[k],
                               **({"adapted_fixed_step": t["fixed_step_losses"][k]}
                                  if k in t.get("fixed_step_losses", {}) else {})} for k in online},
        }
    diagnostics = {t["town"]: t["diagnostics"] for t in towns}
    return {"config": _fingerprint(cfg), "iterations": iterations, "summary": summarize(iterations), "regret": regret,
            "comparison": compare([iterations]), "diagnostics": diagnostics}


def summarize(iterations: list[dict[str, Any]]) -> dict[str, Any]:
    """town -> method -> means (and collision std) over the online rounds."""
    summary: dict[str, dict[str, Any]] = {}
    towns = sorted({t for it in iterations for t in it["towns"]})
    for town in towns:
        rounds = [it["towns"][town] for it in iterations if it["phase"] == "online" and town in it["towns"]]
        summary[town] = {}
        for method in METHODS:
            rows = [r[method] for r in rounds if method in r]
            if not rows:
                continue
            coll = [r["collisions"] for r in rows]
            summary[town][method] = {
                "tracking_cost_mean": statistics.fmean(r["tracking_cost"] for r in rows),
                "collisions_mean": statistics.fmean(coll),
                "collisions_std": statistics.pstdev(coll),
                "completion_mean": statistics.fmean(r["completion"] for r in rows),
                "rounds": len(rows),
            }
    return summary
