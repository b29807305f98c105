"""Shared by the tests that interrupt a study: kill it once a checkpoint is written, then resume it."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path


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
