"""A lab's study session (pernav.play.lab, `pernav session`): the session file, the counterbalanced order, a
2-participant Latin square driven with scripted inputs, the tidy CSV, and resuming after a kill."""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
from play_helpers import kill_when

from pernav.cli import main
from pernav.play.lab import LabSession
from pernav.play.labplan import SessionFileError, block_order, drive_list, load_plan, parse_plan, williams_square

ROOT = Path(__file__).resolve().parents[2]
PLAN = {"name": "t", "participants": ["P1", "P2"], "traffic": 0, "countdown": 0, "seed": 3,
        "defaults": {"town": "Town1"},
        "blocks": [{"name": "rule", "policy": "explore", "routes": [0]},
                   {"name": "oracle", "policy": "oracle", "user": "user3", "routes": [0]}],
        "questionnaire": {"questions": [{"id": "workload", "text": "How hard?", "scale": [1, 7]}]}}


def _write(tmp_path: Path, plan: dict) -> Path:
    import yaml

    path = tmp_path / "session.yaml"
    path.write_text(yaml.safe_dump(plan))
    return path


def _answer(question, block):  # scripted: a different answer per block, to see them land in the right rows
    return 2 if block == "rule" else 6


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 6])
def test_williams_square_is_latin_and_balanced_for_carry_over(n):
    rows = williams_square(n)
    assert len(rows) == (n if n % 2 == 0 else 2 * n)
    for row in rows:
        assert sorted(row) == list(range(n))
    for place in range(n):  # every condition in every place equally often
        counts = [sum(row[place] == c for row in rows) for c in range(n)]
        assert len(set(counts)) == 1
    follows = {pair: 0 for pair in itertools.permutations(range(n), 2)}
    for row in rows:
        for a, b in itertools.pairwise(row):
            follows[a, b] += 1
    assert len(set(follows.values())) <= 1  # each condition directly after every other equally often


def test_latin_order_over_participants_and_seeded_shuffle():
    plan = parse_plan({**PLAN, "participants": ["A", "B", "C"]})
    assert [block_order(plan, p) for p in ("A", "B", "C")] == [[0, 1], [1, 0], [0, 1]]
    shuffled = parse_plan({**PLAN, "counterbalance": "shuffle",
                           "blocks": [{"name": f"b{k}", "routes": [0]} for k in range(5)]})
    first = block_order(shuffled, "P1")
    assert sorted(first) == list(range(5)) and block_order(shuffled, "P1") == first  # seeded: the same each time
    # the same route meets the same world in every block (paired across conditions and participants)
    drives = drive_list(plan, "A")
    assert drives[0].seed == drives[1].seed and drives[0].condition.policy != drives[1].condition.policy


@pytest.mark.parametrize("change, message", [
    ({"weather": "foggy"}, "unknown field 'weather'"),
    ({"counterbalance": "random"}, "counterbalance"),
    ({"participants": ["P1", "P1"]}, "listed twice"),
    ({"participants": "P1"}, "participants"),
    ({"blocks": [{"name": "x", "routes": [99]}]}, "route 99 out of range"),
    ({"blocks": [{"name": "x", "routes": [0], "policy": "adapt"}]}, "unknown policy 'adapt'"),
    ({"blocks": [{"name": "x", "routes": [0], "visual": "snow"}]}, "unknown visual 'snow'"),
    ({"blocks": [{"name": "x", "routes": [0]}, {"name": "x", "routes": [1]}]}, "used twice"),
    ({"questionnaire": {"questions": [{"id": "q", "text": "?", "scale": [5, 1]}]}}, "scale"),
    ({"traffic": -1}, "traffic"),
])
def test_a_bad_session_file_is_refused_by_name(change, message):
    with pytest.raises(SessionFileError, match=message):
        parse_plan({**PLAN, **change})


def test_a_participant_not_in_the_file_is_refused(tmp_path):
    with pytest.raises(SessionFileError, match="'P9' is not in"):
        LabSession(parse_plan(PLAN), "P9", tmp_path)


@pytest.mark.slow
def test_two_participants_of_a_latin_square_with_scripted_inputs(tmp_path):
    plan = load_plan(_write(tmp_path, PLAN))
    for participant in ("P1", "P2"):
        result = LabSession(plan, participant, tmp_path / "out", answer=_answer, announce=lambda s: None).run()
        assert result.finished and not result.stopped
    for participant, order in (("P1", ["rule", "oracle"]), ("P2", ["oracle", "rule"])):
        folder = tmp_path / "out" / participant
        assert json.loads((folder / "session.json").read_text())["order"] == order
        assert (folder / "plan.yaml").read_text() == plan.text
        table = pd.read_csv(folder / "session.csv")  # no arguments: a tidy table
        drives = table[table["row"] == "drive"]
        assert drives["block"].tolist() == order and drives["drive"].tolist() == [1, 2]
        frames = table[table["row"] == "frame"]
        for number in drives["drive"]:  # one frame row per world frame of each drive
            steps = len(table[(table["row"] == "prompt") & (table["drive"] == number)])
            assert len(frames[frames["drive"] == number]) == 10 * steps
        answers = table[table["row"] == "answer"]
        assert dict(zip(answers["block"], answers["answer"], strict=True)) == {"rule": 2, "oracle": 6}
        assert frames["wall_time"].is_monotonic_increasing
        summary = json.loads((folder / "summary.json").read_text())
        assert [d["block"] for d in summary["drives"]] == order
        assert len(list((folder / "drives").glob("*.pt"))) == 2


@pytest.mark.slow
def test_an_existing_session_is_not_overwritten_without_resume(tmp_path):
    plan = parse_plan(PLAN, text="x")
    LabSession(plan, "P1", tmp_path, answer=_answer, announce=lambda s: None).run()
    with pytest.raises(SessionFileError, match="--resume"):
        LabSession(plan, "P1", tmp_path)
    with pytest.raises(SessionFileError, match="differs"):
        LabSession(parse_plan(PLAN, text="y"), "P1", tmp_path, resume=True)
    with pytest.raises(SessionFileError, match="no session to continue"):
        LabSession(plan, "P2", tmp_path, resume=True)


_RUN = """
import sys
from pernav.play.lab import LabSession
from pernav.play.labplan import load_plan
LabSession(load_plan(sys.argv[1]), "P1", sys.argv[2], answer=lambda q, b: 4, resume=len(sys.argv) > 3).run()
"""


@pytest.mark.slow
def test_a_session_killed_mid_drive_resumes_at_the_next_undriven_drive_with_nothing_rewritten(tmp_path):
    plan = {**PLAN, "blocks": [{"name": "rule", "routes": [0, 1]}, {"name": "oracle", "policy": "oracle",
                                                                     "routes": [0]}]}
    path, out = _write(tmp_path, plan), tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    process = subprocess.Popen([sys.executable, "-c", _RUN, str(path), str(out)], env=env)
    progress = out / "P1" / "progress.jsonl"
    # killed 0.3 s after the first drive is committed: well into the second drive
    kill_when(process, lambda: progress.exists() and progress.read_text().count("\n") >= 1, settle=0.3)
    folder = out / "P1"
    first = {p.name: p.read_bytes() for p in (folder / "drives").iterdir()}
    committed = json.loads(progress.read_text().splitlines()[0])
    csv_before = (folder / "session.csv").read_bytes()[: committed["csv_bytes"]]
    done = len(progress.read_text().splitlines())
    result = LabSession(load_plan(path), "P1", out, answer=lambda q, b: 4, resume=True,
                        announce=lambda s: None).run()
    assert result.finished
    for name, data in first.items():  # the drives recorded before the kill are unchanged
        assert (folder / "drives" / name).read_bytes() == data
    assert (folder / "session.csv").read_bytes().startswith(csv_before)
    records = [json.loads(line) for line in progress.read_text().splitlines()]
    assert [r["item"] for r in records] == ["drive:1", "drive:2", "questions:rule", "drive:3", "questions:oracle"]
    assert done >= 1
    table = pd.read_csv(folder / "session.csv")
    assert table[table["row"] == "drive"]["drive"].tolist() == [1, 2, 3]  # no drive twice, none lost


@pytest.mark.slow
def test_the_command_line_checks_and_runs_a_session(tmp_path, capsys):
    path = _write(tmp_path, {k: v for k, v in PLAN.items() if k != "questionnaire"})
    assert main(["session", str(path), "--check"]) == 0
    out = capsys.readouterr().out
    assert "P1: rule/Town1 r0, oracle/Town1 r0" in out and "P2: oracle/Town1 r0, rule/Town1 r0" in out
    assert main(["session", str(path), "--participant", "P2", "--out", str(tmp_path / "o"), "--headless",
                 "--no-audio"]) == 0
    assert "P2: finished, 2 of 2 step(s) done" in capsys.readouterr().out
    code = main(["session", str(path), "--participant", "P2", "--out", str(tmp_path / "o"), "--headless"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "--resume" in err
    bad = tmp_path / "bad.yaml"
    bad.write_text("participants: [P1]\nblocks: [{name: a, routes: [0], weather: foggy}]\n")
    assert main(["session", str(bad), "--check"]) == 2
    assert "the weather is `visual`" in capsys.readouterr().err


def test_the_documented_example_session_file_is_valid():
    plan = load_plan(ROOT / "docs" / "examples" / "session.yaml")
    assert plan.practice is not None and len(plan.blocks) == 2 and len(plan.questions) == 2
    assert [drive_list(plan, p)[1].block for p in plan.participants] == ["explore", "oracle", "explore", "oracle"]
