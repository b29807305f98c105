"""A long study is unbreakable: Ray, SIGKILL at any moment, corrupted checkpoints, NaN losses."""

from __future__ import annotations

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from study_helpers import mini_arguments, mini_config, mini_reference, mini_study, without_wall_time

import pernav.trainer.ensemble as ensemble
import pernav.trainer.ftml as ftml
from pernav.cli import main
from pernav.study import run_study

CMD = [sys.executable, "-m", "pernav.cli", "study"]
ENV = {**os.environ, "OMP_WAIT_POLICY": "PASSIVE"}


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> dict:
    """The uninterrupted single-process mini study (study_helpers.mini_config: the smoke study's offline round and
    first online round, explore, sysid and adapt): where the work ran, or how often it was killed, is what these
    tests change, not which methods ran."""
    return mini_reference(tmp_path_factory)


@pytest.mark.slow
def test_smoke_study_on_local_ray_equals_single_process(reference, tmp_path):
    import ray  # noqa: F401  (an install without the ray extra must fail here, not skip)
    out = tmp_path / "ray"
    # one Ray worker: the mini study is one town, one task (a second worker would only be started and left idle)
    proc = subprocess.run([*CMD, *mini_arguments(tmp_path), "--out", str(out), "--ray", "--workers", "1"], env=ENV,
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-3000:]
    got = json.loads((out / "results.json").read_text())
    assert got["wall_time"]["ray"] is True
    assert without_wall_time(got) == reference


@pytest.mark.slow
def test_sigkill_at_random_moments_then_resume_gives_the_same_results(reference, tmp_path):
    # two kills at random moments (mid-round, between rounds or mid-checkpoint), the second one into the resumed
    # run, then a resume to the end: one study run, two interruptions of either kind. The first kill falls at a random
    # moment after the offline round's checkpoint (so that a resume from a checkpoint is what is tested, however long
    # the offline round takes on the machine), the second at a random moment into the resumed run
    cmd = [*CMD, *mini_arguments(tmp_path)]
    out, rng, report = tmp_path / "killed", random.Random(0), []
    manifest = out / "checkpoints" / "Town1" / "manifest.json"
    for attempt in range(2):
        delay = rng.uniform(0.5, 8.0) if attempt == 0 else rng.uniform(3.0, 10.0)
        proc = subprocess.Popen([*cmd, "--out", str(out), *(["--resume"] if attempt else [])], env=ENV,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.time() + 300
        while attempt == 0 and not manifest.exists() and proc.poll() is None and time.time() < deadline:
            time.sleep(0.05)
        time.sleep(delay)
        killed = proc.poll() is None
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        done = json.loads(manifest.read_text())["index"] + 1 if manifest.exists() else 0
        report.append(f"killed={killed} after {delay:.1f} s with {done} entries checkpointed")
    resumed = subprocess.run([*cmd, "--out", str(out), "--resume"], env=ENV, capture_output=True, text=True)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert without_wall_time(json.loads((out / "results.json").read_text())) == reference
    print("; ".join(report))


@pytest.mark.slow
def test_corrupted_checkpoint_is_reported_with_its_file(tmp_path_factory, tmp_path, capsys):
    out = tmp_path / "study"  # a copy of the finished mini study, its checkpoints then damaged
    shutil.copytree(mini_study(tmp_path_factory), out)
    ckpt = next((out / "checkpoints" / "Town1").glob("entry_*"))
    state = ckpt / "state.pt"
    data = bytearray(state.read_bytes())
    data[len(data) // 2] ^= 0xFF
    state.write_bytes(bytes(data))
    before = (out / "results.json").read_text()
    from pernav.study import checkpoints

    with pytest.raises(checkpoints.CheckpointError, match="state.pt"):
        checkpoints.load_checkpoint(out / "checkpoints" / "Town1", {})
    # through the CLI: one line naming the file, exit code 2, results untouched
    argv = ["study", *mini_arguments(tmp_path), "--out", str(out), "--resume"]
    capsys.readouterr()
    code = main(argv)
    errors = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert code == 2 and len(errors) == 1 and "state.pt" in errors[0] and "corrupted" in errors[0]
    assert (out / "results.json").read_text() == before
    (out / "checkpoints" / "Town1" / "manifest.json").write_text("{not json")
    assert main(argv) == 2
    assert "manifest.json" in capsys.readouterr().err


@pytest.mark.slow
def test_nan_loss_is_skipped_and_the_study_finishes(tmp_path, monkeypatch, caplog):
    real = ftml.multistep_loss
    calls = {"n": 0}

    def sometimes_nan(*args, **kwargs):
        calls["n"] += 1
        loss = real(*args, **kwargs)
        return loss * torch.tensor(float("nan")) if calls["n"] in (5, 30) else loss

    # single models train through ftml, ensembles through one batched pass in ensemble: NaN both
    monkeypatch.setattr(ftml, "multistep_loss", sometimes_nan)
    monkeypatch.setattr(ensemble, "multistep_loss", sometimes_nan)
    # the mini study less adapt_driver (it trains no network: no loss of its can be NaN): both NaN losses fall in its
    # offline round's warm start, and its online round evaluates and trains what the warm start left
    cfg = mini_config()
    cfg.methods = ["explore", "sysid", "adapt"]
    results = run_study(cfg, tmp_path / "nan", report=False)
    skipped = sum(results["diagnostics"]["Town1"][name]["skipped_updates"] for name in ("sysid", "adapt"))
    assert skipped >= 2  # the 7-action warm start (shared by sysid and adapt) and the 21-action one
    assert "non-finite model loss" in caplog.text
    for it in results["iterations"]:
        for figures in it["towns"]["Town1"].values():
            assert figures["tracking_cost"] == figures["tracking_cost"]  # not NaN
    for name in ("sysid", "adapt"):
        members = torch.load(Path(tmp_path / "nan" / "checkpoints" / "Town1").glob("entry_*").__next__() / "state.pt",
                             weights_only=False)["learners"][name]["members"]
        assert members and all(torch.isfinite(v).all() for m in members for v in m["model"].values())


@pytest.mark.slow
def test_pool_workers_exit_when_the_study_process_is_killed(tmp_path):
    # a killed `pernav study` must not leave its spawned workers computing (they outlived SIGTERM before)
    import os
    import signal
    import subprocess
    import sys
    import time

    script = tmp_path / "parent.py"
    script.write_text(
        "import os, sys, time\n"
        "from pernav.study.parallel import PoolExecutor\n"
        "if __name__ == '__main__':\n"
        "    ex = PoolExecutor(2)\n"
        "    pids = {f.result() for f in [ex.pool.submit(os.getpid) for _ in range(8)]}\n"
        "    print(' '.join(map(str, pids)), flush=True)\n"
        "    time.sleep(600)\n")
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    pids = [int(p) for p in parent.stdout.readline().split()]
    assert pids and parent.pid not in pids
    parent.send_signal(signal.SIGKILL)
    parent.wait()

    def alive(pid: int) -> bool:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        try:
            with open(f"/proc/{pid}/stat") as f:  # a zombie waiting for init to reap it is gone too
                return f.read().split(")")[-1].split()[0] != "Z"
        except FileNotFoundError:
            return False

    deadline = time.time() + 20
    while any(alive(p) for p in pids) and time.time() < deadline:
        time.sleep(0.2)
    assert not any(alive(p) for p in pids)


@pytest.mark.slow
def test_a_pool_worker_that_starts_after_its_parent_died_exits():
    # a worker spawned just before its parent was killed reads os.getppid() as init's pid: it must not wait for
    # init to exit (one such worker outlived a test run)
    import subprocess
    import sys

    code = "from pernav.study.parallel import init_worker\ninit_worker(parent=2 ** 22 + 1)\nprint('still here')"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1 and "still here" not in proc.stdout
