"""The diagnostics of pernav.diagnostics as commands (``python -m pernav.diagnostics.X`` and ``pernav diagnose``):
they say what they show, how long they take and how to run them, and refuse bad input with exit code 2."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

from pernav.cli import main

ROOT = Path(__file__).resolve().parents[2]
DIAGNOSTICS = ("model_check", "planning_error")


@pytest.mark.parametrize("name", DIAGNOSTICS)
def test_each_diagnostic_says_what_it_shows_how_long_it_takes_and_how_to_run_it(name: str) -> None:
    path = ROOT / "pernav" / "diagnostics" / f"{name}.py"
    doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
    assert len(doc.splitlines()) >= 3 and "minutes" in doc
    assert f"python -m pernav.diagnostics.{name}" in doc and "pernav diagnose" in doc


@pytest.mark.slow
def test_planning_error_resume_refuses_to_mix_retime_defaults_and_leaves_the_file(tmp_path):
    from pernav.diagnostics.panel import PANEL

    driver = next(iter(PANEL))
    kept = tmp_path / "kept.json"  # one retime@true episode, written before the defaults were recorded
    kept.write_text(json.dumps({"drivers": {}, "episodes": [
        {"driver": driver, "town": "Town1", "route": 0, "seed": 1000, "method": "retime@true", "tracking_cost": 1.0}]}))
    before = kept.read_text()
    out = subprocess.run([sys.executable, "-m", "pernav.diagnostics.planning_error", "--routes", "1", "--paper-routes",
                          "0", "--drivers", driver, "--json", str(kept), "--resume"],
                         capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 2 and "would mix" in out.stderr and "Traceback" not in out.stderr
    assert kept.read_text() == before


def test_planning_error_counts_an_option_added_later_as_off_in_files_written_before_it():
    from pernav.diagnostics.planning_error import _same_defaults as same
    from pernav.planner.factory import PLANNER_DEFAULTS

    current = PLANNER_DEFAULTS["retime"]
    added = next(reversed(current))  # an option a file written before it does not record
    before = {k: v for k, v in current.items() if k != added}
    assert same(before, current) and same(current, current)
    assert not same({**before, "delay": current["delay"] + 3}, current) and not same(None, current)
    assert not same({**current, added: "something else"}, current)
    # the options removed since, recorded off (as docs/figures/planning_error.json has them), drove as today
    assert same({**current, "rescue": None, "rescue_evidence": True, "route_goals": False}, current)
    assert not same({**current, "rescue": 8.0}, current)


def test_pernav_diagnose_unknown_diagnostic_one_line_exit_2(capsys):
    assert main(["diagnose", "nonsense", "--routes", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert err.startswith("pernav diagnose: error:") and "'nonsense'" in err and "model, planning" in err


def test_pernav_diagnose_planning_help_lists_the_diagnostics_options(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["diagnose", "planning", "--help"])
    out = capsys.readouterr().out
    assert exit_.value.code == 0 and out.startswith("usage: pernav diagnose planning")
    for option in ("--routes", "--paper-routes", "--samples", "--drivers", "--workers", "--json", "--resume", "--plot",
                   "--planner-option"):
        assert option in out, option


def test_pernav_diagnose_model_without_a_finished_study_exit_2(tmp_path, capsys):
    import torch

    threads = torch.get_num_threads()  # model_check runs on one thread
    try:
        assert main(["diagnose", "model", "--study", str(tmp_path), "--town", "Town3"]) == 2
    finally:
        torch.set_num_threads(threads)
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "holds no pernav study" in err


@pytest.mark.parametrize("first", ["-1", "6", "7"])
def test_pernav_diagnose_model_refuses_held_out_episodes_that_hold_taus_route_exit_2(tmp_path, capsys, first):
    with pytest.raises(SystemExit) as exit_:
        main(["diagnose", "model", "--study", str(tmp_path), "--first-episode", first])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "Traceback" not in err and "--first-episode must be >= 0" in err
    assert f"got {first}" in err.splitlines()[-1]


@pytest.mark.slow
def test_the_model_check_pairs_explores_next_prompts_with_the_same_prompts_later():
    """At each approach state the diagnostic's pair is explore's next prompts now and the same DELAY s later."""
    from pernav.diagnostics.model_check import DELAY, STEPS, approach_pairs
    from pernav.diagnostics.panel import PANEL

    pairs = list(approach_pairs(next(iter(PANEL)), "Town1", episodes=1))
    assert pairs
    for td, _, _, (now, later) in pairs:
        assert len(now) == max(STEPS) and bool(now.any()) and not bool(later[:DELAY].any())
        assert bool((later[DELAY:] == now[:-DELAY]).all())
        future = td["explore_future"]
        assert not bool(future[0]) and bool(future[1:5].any())  # a prompt of explore's plan due in 1-4 steps
