"""Shared by the study tests: one uninterrupted smoke study per test session (Town1 and Town2 on a pool of two), one
of the mini study (the smoke study cut to what the tests of Ray, SIGKILL, NaN losses and a re-timed tau need), and
killing a study once a checkpoint is written, then resuming it."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path
from typing import Any

from navigation_helpers import TIME_LIMIT, shared_folder


def kill_then_resume(cmd: list[str], out: Path, town: str, index: int, timeout: float = 300.0) -> dict:
    """Run ``cmd`` (a ``pernav study`` command writing to ``out``), SIGKILL it once ``town``'s checkpoint of
    entry ``index`` is written, check nothing was reported, resume with ``--resume``, return its results.json."""
    env = {**os.environ, "OMP_WAIT_POLICY": "PASSIVE"}
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    manifest = out / "checkpoints" / town / "manifest.json"
    deadline = time.time() + timeout
    while time.time() < deadline and proc.poll() is None:
        try:
            if manifest.exists() and json.loads(manifest.read_text())["index"] >= index:
                break
        except json.JSONDecodeError:  # caught between two writes: look again
            pass
        time.sleep(0.05)
    assert proc.poll() is None, "the study finished before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (out / "results.json").exists()
    resumed = subprocess.run([*cmd, "--resume"], env=env, capture_output=True, text=True)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    return json.loads((out / "results.json").read_text())


def without_wall_time(results: dict) -> dict:
    """``results`` as results.json holds it, less its ``wall_time`` (wall-clock seconds: they differ run to run)."""
    return json.loads(json.dumps({k: v for k, v in results.items() if k != "wall_time"}))


def shared_study(tmp_path_factory, name: str, cfg: Any = None, workers: int = 1) -> Path:
    """The study ``cfg`` (default: the smoke preset, Town1) with ``workers``, run once per test session
    (:func:`shared_folder`): the tests that compare an interrupted, resumed, parallel or Ray-run study against it do
    not each run it again. Returns the study folder."""
    from pernav.study import preset, run_study

    def build(out: Path) -> None:
        results = run_study(preset("smoke") if cfg is None else cfg, out, workers=workers)
        assert json.loads(json.dumps(results)) == json.loads((out / "results.json").read_text())  # as returned

    return shared_folder(tmp_path_factory, name, build)


# the mini study: the smoke preset's first two rounds (offline, then one online round: a checkpoint to resume from
# and an evaluation after it) with explore, the two model learners (sysid, adapt: their buffers, ensembles and
# meta-learner state are what a resume must restore) and adapt_driver (its meta model, evidence and estimates): about
# 30 s, against 2 minutes for the smoke study
MINI_METHODS = ("explore", "sysid", "adapt", "adapt_driver")
MINI_ROUNDS = 2


def mini_config() -> Any:
    """The mini study's configuration (the methods in the order ``pernav study --methods`` gives them; episodes cut at
    :data:`TIME_LIMIT`)."""
    from pernav.study import preset
    from pernav.study.config import METHODS

    cfg = preset("smoke")
    cfg.methods = [m for m in METHODS if m in MINI_METHODS]
    cfg.schedule = cfg.schedule[:MINI_ROUNDS]
    cfg.time_limit_factor = TIME_LIMIT
    return cfg


def mini_arguments(folder: Path) -> list[str]:
    """The ``pernav study`` options that run :func:`mini_config` (its schedule written to a file in ``folder``)."""
    schedule = folder / "mini_schedule.json"
    schedule.write_text(json.dumps([{k: v for k, v in e.to_dict().items() if v is not None}
                                    for e in mini_config().schedule]))
    return ["--preset", "smoke", "--methods", *MINI_METHODS, "--schedule", str(schedule), "--time-limit-factor",
            str(TIME_LIMIT)]


def mini_study(tmp_path_factory) -> Path:
    """The uninterrupted single-process mini study (:func:`mini_config`), run once per test session: its folder."""
    return shared_study(tmp_path_factory, "mini_reference", mini_config())


def mini_reference(tmp_path_factory) -> dict:
    """The uninterrupted single-process mini study's results, less its wall time."""
    return without_wall_time(json.loads((mini_study(tmp_path_factory) / "results.json").read_text()))


def two_towns() -> Any:
    """The smoke study (episodes cut at :data:`TIME_LIMIT`) of Town1 and Town2, Town2 without the last round: Town1 the
    whole smoke study, Town2 (its offline round and an online one, every method) the town beside it."""
    import dataclasses

    from pernav.study import preset

    cfg = preset("smoke")
    cfg.towns, cfg.time_limit_factor = ["Town1", "Town2"], TIME_LIMIT
    *rounds, last = cfg.schedule
    cfg.schedule = [*rounds, dataclasses.replace(last, towns=("Town1",))]
    return cfg


def smoke_study(tmp_path_factory) -> Path:
    """:func:`two_towns` on a pool of two workers (each town in a process of its own), run once per test session:
    the shared smoke study. Its Town1 is the whole smoke study (every method, every round). Returns its folder."""
    return shared_study(tmp_path_factory, "smoke_two_workers", two_towns(), workers=2)
