"""The online study: towns in parallel, results.json (docs/study.md), report and figures.

Example (the smoke preset, ~1 minute):
    >>> from pernav.study import preset, run_study
    >>> results = run_study(preset("smoke"), "/tmp/pernav-smoke")      # doctest: +SKIP
    >>> sorted(results)                                                 # doctest: +SKIP
    ['comparison', 'config', 'diagnostics', 'iterations', 'regret', 'summary', 'wall_time']
"""

from __future__ import annotations

import json
import logging
import multiprocessing
import os
import statistics
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from pernav.study.compare import compare
from pernav.study.config import BELIEF_DEFAULTS, METHODS, TIMING_DEFAULTS, StudyConfig, current_names
from pernav.study.parallel import init_worker, make_executor
from pernav.study.report import running_mean, write_report
from pernav.study.runner import run_town

__all__ = ["OutputError", "check_output", "run_study", "summarize"]

class OutputError(ValueError):
    """The output folder cannot be used (it holds a different study, or a study without --resume)."""


def _fingerprint(cfg: StudyConfig) -> dict[str, Any]:
    return json.loads(json.dumps(cfg.to_dict()))


# Options added after studies had been saved, each with the value that reproduces a study from before it: a
# saved study.json that lacks one of these ran with that value. Any other missing option (e.g. train.backtrack,
# whose default changed what an older study did) makes the folder a different study.
ADDED_OPTIONS: dict[str, Any] = {"collect": "explore", "tau_policy": "explore", "calibration": 0, "train.ensemble": 1,
                                 "train.personal_updates": 0, "train.personal_replay": 0.0, "train.road": 0,
                                 "train.context": 0, "timing": TIMING_DEFAULTS, "belief": BELIEF_DEFAULTS,
                                 "time_limit_factor": None}


def _difference(saved: dict[str, Any], current: dict[str, Any], prefix: str = "") -> str | None:
    """Why two fingerprints differ (naming the first option, dotted), or None when they are the same study."""
    for key in current:
        name = prefix + key
        if key not in saved:
            if name not in ADDED_OPTIONS:
                return f"its {name!r} is not recorded (saved by an older pernav)"
            if current[key] != ADDED_OPTIONS[name]:
                return f"its {name!r} differs: it predates the option and ran with {ADDED_OPTIONS[name]!r}"
            continue
        if prefix == "" and key == "train" and isinstance(saved[key], dict) and isinstance(current[key], dict):
            inner = _difference(saved[key], current[key], "train.")
            if inner:
                return inner
        elif saved[key] != current[key]:
            return f"its {name!r} differs"
    gone = next((k for k in saved if k not in current), None)
    return None if gone is None else f"its {prefix + gone!r} is no longer an option"


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
        diff = _difference(current_names(saved), _fingerprint(cfg)) if isinstance(saved, dict) \
            else "it is not a configuration"
        if diff:
            raise OutputError(f"output folder {str(out)!r} holds a different study ({diff}); choose another --out")
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
        with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=init_worker,
                                 initargs=(os.getpid(),)) as pool:
            towns = list(pool.map(_town_job, jobs))
    else:
        executor = make_executor(workers)
        try:
            towns = [run_town(cfg, town, out, resume=resume, executor=executor) for town in cfg.towns]
        finally:
            executor.close()
    results = assemble(cfg, towns)
    results["wall_time"] = {"wall_s": round(time.perf_counter() - t0, 1), "workers": workers, "ray": ray,
                            "towns": {t["town"]: t["wall_time"] for t in towns},
                            "profile": {t["town"]: t["profile"] for t in towns}}
    tmp = out / ".results.json.tmp"
    tmp.write_text(json.dumps(results, indent=1))
    os.replace(tmp, out / "results.json")
    if report:
        write_report(results, out)
    return results


def _run_on_ray(cfg: StudyConfig, out: Path, resume: bool, workers: int, address: str | None) -> list[dict[str, Any]]:
    try:
        import ray  # lazy: an optional dependency (pernav[ray])
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
        if t.get("driver_regret"):  # adapt_driver's FTML against its best meta model in hindsight (model loss)
            regret[t["town"]]["adapt_driver"] = t["driver_regret"]
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
