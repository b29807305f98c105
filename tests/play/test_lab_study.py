"""A lab study of personalized navigation (`pernav session` with a finished study): learners as conditions, data that
cannot be lost, the protocol's screens and the SSQ, analysis-ready tables and the docs' example analysis.

One module-scoped session (three participants, an explore, a belief and an adapt block, on a small study built once
per test session) serves most tests; the refusals of a folder need no drive."""

from __future__ import annotations

import inspect
import io
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import torch
import yaml
from navigation_helpers import shared_folder
from play_helpers import kill_when, lab_study

from pernav.cli import main
from pernav.play import ssq
from pernav.play.audio import SPEECH_DIR, Speaker
from pernav.play.lab import LabOptions, LabSession
from pernav.play.labdata import ANSWER_TABLE, DRIVE_TABLE
from pernav.play.labplan import SessionFileError, load_plan, parse_plan, square_warning

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

ROOT = Path(__file__).resolve().parents[2]
PEOPLE = ["S01", "S02", "S03"]
BLOCK_NAMES = ("baseline", "bayes", "meta")  # never shown to a participant
POLICY_NAMES = ("explore", "belief", "adapt", "oracle", "timing")


def _plan(study: Path) -> dict:
    return {"name": "lab", "participants": PEOPLE, "traffic": 0, "countdown": 0, "seed": 1, "study": str(study),
            "consent": "I agree to take part.", "instructions": "Follow the voice's prompts.", "break_s": 0,
            "ssq": ["before", "after_block"], "show_learned": True, "defaults": {"town": "Town1"},
            "blocks": [{"name": "baseline", "policy": "explore", "routes": [0]},
                       {"name": "bayes", "policy": "belief", "routes": [0], "counters": False},
                       {"name": "meta", "policy": "adapt", "routes": [0]}],
            "questionnaire": {"questions": [{"id": "workload", "text": "How hard?", "scale": [1, 7]},
                                            {"id": "comment", "text": "Anything to add?"}]}}


def _answer(question, block):  # scripted: a rating per block, a symptom rated 1 after the belief block
    if question.id.startswith("ssq_"):
        return 1 if block == "bayes" and question.id == "ssq_nausea" else 0
    if question.scale is None:
        return f"fine, {block}"
    return {"baseline": 2, "bayes": 5, "meta": 6}[block]


def _write(folder: Path, plan: dict) -> Path:
    path = folder / "session.yaml"
    path.write_text(yaml.safe_dump(plan))
    return path


def _bytes(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    return lab_study(tmp_path_factory)


@pytest.fixture
def named(tmp_path):
    """What a session file's checks read of a finished study (its settings only): explore, adapt and belief in
    Town1, without building one."""
    folder = tmp_path / "named_study"
    folder.mkdir()
    (folder / "study.json").write_text(json.dumps({"towns": ["Town1"], "methods": ["explore", "adapt", "belief"]}))
    (folder / "results.json").write_text("{}")
    return folder


@pytest.fixture(scope="module")
def lab(study, tmp_path_factory):
    """Three participants' whole sessions, headless (the scripted bot drives; scripted answers), run once per test
    session for both pytest workers (the tests only read them): a module fixture would run them again on each worker,
    and again whenever the test order leaves this module and comes back."""

    def build(base: Path) -> None:
        plan = load_plan(_write(base, _plan(study)))
        lines: list[str] = []
        for participant in PEOPLE:
            result = LabSession(plan, participant, base / "out", answer=_answer, announce=lines.append).run()
            assert result.finished and not result.stopped
        (base / "announced.json").write_text(json.dumps(lines))

    base = shared_folder(tmp_path_factory, "lab_sessions", build)
    return base, base / "session.yaml", json.loads((base / "announced.json").read_text())


@pytest.mark.slow
def test_three_participants_drive_the_learners_as_counterbalanced_conditions(lab):
    base, _, lines = lab
    orders = {p: json.loads((base / "out" / p / "session.json").read_text())["order"] for p in PEOPLE}
    assert orders == {"S01": ["baseline", "bayes", "meta"], "S02": ["bayes", "meta", "baseline"],
                      "S03": ["meta", "baseline", "bayes"]}
    for participant in PEOPLE:
        folder = base / "out" / participant
        drives = pd.read_csv(folder / "drives.csv")
        assert drives["block"].tolist() == orders[participant] and drives["position"].tolist() == [1, 2, 3]
        assert dict(zip(drives["block"], drives["policy"], strict=True)) == {"baseline": "explore", "bayes": "belief",
                                                                            "meta": "adapt"}
        assert (drives["collisions"] == drives["vehicle_collisions"] + drives["edge_strikes"]).all()
        assert (drives["completed"] == 1).all() and drives["counters"].tolist() == [
            int(b != "bayes") for b in orders[participant]]
        saved = torch.load(folder / "belief.pt", weights_only=False)
        # the belief read every whole drive of the participant before its block (S02 drives it first: none)
        before = orders[participant].index("bayes")
        assert len(saved["read"]["Town1"]) >= before
        records = [json.loads(x) for x in (folder / "progress.jsonl").read_text().splitlines()]
        learned = [r for r in records if r["item"].startswith("learned:")]
        assert [r["item"] for r in learned] == [f"learned:{b}" for b in orders[participant] if b != "baseline"]
        assert any("you react about" in line for r in learned for line in r["shown"])
        events = [json.loads(x)["event"] for x in (folder / "events.jsonl").read_text().splitlines()]
        assert events[0] == "start" and events[-1] == "end" and "consent" in events and "killed" not in events
        assert events.count("break") == 2  # between the first and second blocks, and the second and third
    assert any("you react about" in line for line in lines)


@pytest.mark.slow
def test_the_tables_are_typed_and_described_by_the_data_dictionary(lab):
    base, _, _ = lab
    folder = base / "out" / "S01"
    drives, answers = pd.read_csv(folder / "drives.csv"), pd.read_csv(folder / "answers.csv")
    assert list(drives.columns) == [c[0] for c in DRIVE_TABLE] and list(answers.columns) == [c[0] for c in ANSWER_TABLE]
    for table, frame in (("drives.csv", drives), ("answers.csv", answers)):
        for column, kind, *_ in (DRIVE_TABLE if table == "drives.csv" else ANSWER_TABLE):
            if kind == "int":
                assert frame[column].dtype == "int64", (table, column)
    assert answers["value"].dtype == "float64"
    workload = answers[answers["question"] == "workload"]
    assert dict(zip(workload["block"], workload["value"], strict=True)) == {"baseline": 2, "bayes": 5, "meta": 6}
    assert workload["policy"].tolist() == ["explore", "belief", "adapt"] and workload["drive"].tolist() == [1, 2, 3]
    comment = answers[answers["question"] == "comment"]
    assert comment["text"].tolist() == ["fine, baseline", "fine, bayes", "fine, meta"] and comment["value"].isna().all()
    dictionary = pd.read_csv(folder / "dictionary.csv")
    assert list(dictionary.columns) == ["table", "column", "type", "unit", "meaning"]
    session = pd.read_csv(folder / "session.csv")
    for table, frame in (("drives.csv", drives), ("answers.csv", answers), ("session.csv", session)):
        described = dictionary[dictionary["table"] == table]
        assert described["column"].tolist() == list(frame.columns) and described["meaning"].notna().all()
    assert dictionary.set_index(["table", "column"]).loc[("drives.csv", "tracking_cost"), "unit"] == "cost units"
    assert session["position"].dtype == "int64" and session["drive"].dtype == "int64"


@pytest.mark.slow
def test_the_ssq_is_asked_before_and_after_each_block_with_its_published_weights(lab):
    base, _, _ = lab
    answers = pd.read_csv(base / "out" / "S02" / "answers.csv")
    scored = answers[answers["questionnaire"] == "ssq"]
    assert scored.groupby("when")["question"].count().to_dict() == {"after_block": 3 * 20, "before": 20}
    totals = scored[scored["question"] == "ssq_total"].set_index("block")["value"]
    assert totals.loc["bayes"] == pytest.approx(2 * 3.74) and totals.loc["baseline"] == 0  # nausea: N and D
    nausea = scored[(scored["question"] == "ssq_nausea_score") & (scored["block"] == "bayes")]["value"].item()
    assert nausea == pytest.approx(9.54)
    assert len(ssq.ITEMS) == 16 and ssq.WEIGHTS == {"nausea": 9.54, "oculomotor": 7.58, "disorientation": 13.92,
                                                    "total": 3.74}
    assert all(sum(s in item.loads for item in ssq.ITEMS) == 7 for s in "NOD")


@pytest.mark.slow
def test_each_prompt_has_a_reaction_read_from_the_frames(lab):
    base, _, _ = lab
    session = pd.read_csv(base / "out" / "S01" / "session.csv")
    prompts = session[(session["row"] == "prompt") & (session["played"] == 1)]
    read = prompts["reaction_s"].dropna()
    assert len(read) > 0 and (read > 0).all() and (read <= 9.0).all()
    assert prompts[~prompts["instruction"].str.contains("turn|prepare")]["reaction_s"].isna().all()
    drives = pd.read_csv(base / "out" / "S01" / "drives.csv")
    assert drives["reaction_turn_s"].notna().any()


def _docs_analysis() -> str:
    text = (ROOT / "docs" / "human.md").read_text()
    (block,) = re.findall(r"<!-- analysis example -->\n```python\n(.*?)```", text, flags=re.S)
    return block


@pytest.mark.slow
def test_the_docs_example_analysis_runs_on_a_generated_session(lab, monkeypatch, capsys):
    base, _, _ = lab
    monkeypatch.chdir(base)  # the example reads out/*/
    namespace: dict = {"__name__": "__docs__"}
    exec(compile(_docs_analysis(), "docs/human.md[analysis]", "exec"), namespace)  # noqa: S102
    table = namespace["table"]
    assert list(table.index.names) == ["participant", "policy"] and len(table) == 9
    assert list(table.columns) == ["tracking_cost", "collisions", "missed_turns", "reaction_turn_s",
                                   "ssq_total"]
    assert table.loc[("S02", "belief"), "ssq_total"] == pytest.approx(2 * 3.74)
    assert table["tracking_cost"].notna().all()
    assert "S01" in capsys.readouterr().out


_RUN = """
import inspect, sys
from pernav.play.lab import LabSession
from pernav.play.labplan import load_plan
exec(sys.argv[3])
LabSession(load_plan(sys.argv[1]), "S01", sys.argv[2], answer=_answer, announce=lambda s: None).run()
"""


@pytest.mark.slow
def test_a_session_killed_in_the_belief_block_resumes_with_its_belief_intact(lab, tmp_path):
    base, path, _ = lab
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    answer = inspect.getsource(_answer)
    process = subprocess.Popen([sys.executable, "-c", _RUN, str(path), str(out), answer], env=env)
    progress = out / "S01" / "progress.jsonl"
    # killed in the belief block's drive: 0.4 s after the SSQ that follows the first block is committed
    kill_when(process, lambda: progress.exists() and "ssq:baseline" in progress.read_text(), settle=0.4)
    folder = out / "S01"
    before = _bytes(folder)
    state = before.pop("belief.pt", None)  # the learner's state: written whole after each drive it reads
    kept = [] if state is None else torch.load(io.BytesIO(state), weights_only=False)["history"]
    assert json.loads(progress.read_text().splitlines()[-1])["item"] == "ssq:baseline"
    result = LabSession(load_plan(path), "S01", out, answer=_answer, resume=True, announce=lambda s: None).run()
    assert result.finished
    for name, data in before.items():  # nothing recorded before the kill is truncated or replaced
        now = (folder / name).read_bytes() if (folder / name).exists() else None
        assert now is not None and now.startswith(data) or name.startswith("drives/") and now is None, name
    events = [json.loads(x)["event"] for x in (folder / "events.jsonl").read_text().splitlines()]
    assert events.count("start") == 1 and events.count("killed") == 1 and events.count("resume") == 1
    assert events.index("killed") < events.index("resume") and events[-1] == "end"
    mine, reference = (torch.load(f / "belief.pt", weights_only=False) for f in (folder, base / "out" / "S01"))
    assert mine["history"] == reference["history"] and mine["read"] == reference["read"]  # as if never killed
    assert mine["history"][: len(kept)] == kept
    ours, theirs = mine["beliefs"]["Town1"], reference["beliefs"]["Town1"]
    assert torch.equal(ours["log_post"], theirs["log_post"]) and ours["answers"] == theirs["answers"]
    drives = pd.read_csv(folder / "drives.csv")
    assert drives["drive"].tolist() == [1, 2, 3] and drives["block"].tolist() == ["baseline", "bayes", "meta"]
    assert pd.read_csv(folder / "session.csv").query("row == 'drive'")["drive"].tolist() == [1, 2, 3]


# ----- data that cannot be lost: each refused with exit 2, one line, every byte unchanged ------------------------
def _session(capsys, *args: str) -> tuple[int, str]:
    code = main(["session", *args])
    return code, capsys.readouterr().err


def _refused(capsys, path: Path, participant: str, out: Path, watched: Path, *more: str) -> str:
    """``pernav session path --participant P --out OUT --headless --no-audio ...``: exit 2, one line, and every byte
    under ``watched`` as it was. Returns the line."""
    before = _bytes(watched)
    code, err = _session(capsys, str(path), "--participant", participant, "--out", str(out), "--headless",
                         "--no-audio", *more)
    assert code == 2 and err.count("\n") == 1 and _bytes(watched) == before
    return err


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """S01's finished session of a one-drive file without a study (what the refusals copy and mix up)."""
    base = tmp_path_factory.mktemp("small")
    path = _write(base, {"participants": PEOPLE, "traffic": 0, "countdown": 0,
                         "blocks": [{"name": "baseline", "routes": [0]}]})
    assert LabSession(load_plan(path), "S01", base / "out", announce=lambda s: None).run().finished
    return base / "out", path


def test_a_folder_holding_another_participants_data_is_refused(finished, tmp_path, capsys):
    out, path = finished
    mixed = tmp_path / "out3"
    (mixed / "S02" / "drives").mkdir(parents=True)
    shutil.copy(out / "S01" / "session.csv", mixed / "S02" / "session.csv")
    shutil.copytree(out / "S01" / "drives", mixed / "S02" / "drives", dirs_exist_ok=True)
    assert "did not write" in _refused(capsys, path, "S02", mixed, mixed)
    other = tmp_path / "other"
    (other / "S02").mkdir(parents=True)
    shutil.copy(out / "S01" / "session.json", other / "S02" / "session.json")
    assert "--resume" in _refused(capsys, path, "S02", other, other)


def test_a_copied_folder_resumed_as_another_participant_is_refused(finished, tmp_path, capsys):
    out, path = finished
    copy = tmp_path / "out"
    shutil.copytree(out / "S01", copy / "S02")
    assert "'S01'" in _refused(capsys, path, "S02", copy, copy, "--resume")


def test_an_out_folder_that_is_a_participants_folder_is_refused(finished, tmp_path, capsys):
    out, path = finished
    copy = tmp_path / "out"
    shutil.copytree(out / "S01", copy / "S01")
    assert "participant's folder" in _refused(capsys, path, "S02", copy / "S01", copy)


@pytest.mark.parametrize("extra", ["notes.csv", "drives/99-other-Town1-r0.pt"])
def test_a_folder_with_files_the_session_did_not_write_is_not_resumed(finished, tmp_path, capsys, extra):
    out, path = finished
    copy = tmp_path / "out"
    shutil.copytree(out / "S01", copy / "S01")
    (copy / "S01" / extra).write_text("someone else's")
    assert extra in _refused(capsys, path, "S01", copy, copy, "--resume")


def test_files_saved_but_not_committed_are_kept_under_an_attempt_name(finished, tmp_path):
    """As a kill after the last drive's files were saved, before its record: the files are renamed, not replaced;
    a progress line cut short is ended, not cut."""
    out, path = finished
    folder = tmp_path / "out" / "S01"
    shutil.copytree(out / "S01", folder)
    lines = (folder / "progress.jsonl").read_text().splitlines(keepends=True)
    last = max(k for k, line in enumerate(lines) if json.loads(line)["item"].startswith("drive:"))
    cut: dict[str, int] = {}  # the tables as they were before the drive's record (its rows come after it)
    for line in lines[last:]:
        for table, span in json.loads(line)["appends"].items():
            cut[table] = min(cut.get(table, span["at"]), span["at"])
    for table, size in cut.items():
        (folder / table).write_bytes((folder / table).read_bytes()[:size])
    (folder / "progress.jsonl").write_text("".join(lines[:last]) + lines[last][:40])  # as a kill left it
    (folder / "summary.json").unlink()
    events = folder / "events.jsonl"
    events.write_text(events.read_text().rsplit('{"event": "end"', 1)[0])  # the run never ended
    saved = {p.name: p.read_bytes() for p in (folder / "drives").glob("01-*")}
    assert len(saved) == 3
    result = LabSession(load_plan(path), "S01", tmp_path / "out", answer=_answer, resume=True,
                        announce=lambda s: None).run()
    assert result.finished
    for name, data in saved.items():
        stem, suffix = name.split(".", 1)
        assert (folder / "drives" / f"{stem}-killed1.{suffix}").read_bytes() == data  # kept, under an attempt name
        assert (folder / "drives" / name).exists()  # the drive driven again
    kept = [json.loads(x) for x in events.read_text().splitlines() if '"kept"' in x]
    assert len(kept) == 4 and [json.loads(x)["event"] for x in events.read_text().splitlines()].count("killed") == 1
    assert (folder / "progress.jsonl").read_text().startswith("".join(lines[:last]) + lines[last][:40] + "\n")
    assert pd.read_csv(folder / "drives.csv")["drive"].tolist() == [1]


# ----- refusals of a bad file or missing answers ----------------------------------------------------------------
@pytest.mark.parametrize("change, message", [
    ({"hide_cost": "no"}, "hide_cost: expected true or false, got 'no'"),
    ({"show_learned": 1}, "show_learned: expected true or false"),
    ({"ssq": ["during"]}, "ssq: expected true, false or a list of moments from before, after_block, after"),
    ({"audio": {"volume": 2}}, "audio.volume: expected a number from 0"),
    ({"audio": {"voice": "nowhere"}}, "audio.voice: 'nowhere' lacks"),
    ({"audio": {"playback": "fast"}}, "unknown playback 'fast'"),
    ({"blocks": [{"name": "x", "routes": [0], "policy": "belief"}]}, "needs a finished study"),
    ({"blocks": [{"name": "x", "routes": [0], "counters": "off"}]}, "counters: expected true or false"),
    ({"study": "/nonexistent"}, "study: no study folder"),
    ({"consent": 3}, "consent: expected a text"),
])
def test_a_bad_field_is_refused_by_name(change, message, tmp_path):
    plan = {"participants": ["P1"], "blocks": [{"name": "x", "routes": [0]}], **change}
    with pytest.raises(SessionFileError, match=re.escape(message)):
        parse_plan(plan, base=tmp_path)


def test_a_learner_the_study_did_not_run_is_refused_by_name(named):
    plan = {"participants": ["P1"], "study": str(named), "blocks": [{"name": "x", "routes": [0], "policy": "timing"}]}
    with pytest.raises(SessionFileError, match="unknown policy 'timing'; choose one of explore, oracle or a learner "
                                               "of the study \\(adapt, belief\\)"):
        parse_plan(plan)


def test_headless_without_answers_on_stdin_is_refused_before_anything_is_written(named, tmp_path, capsys,
                                                                                  monkeypatch):
    path = _write(tmp_path, _plan(named))
    monkeypatch.setattr(sys, "stdin", io.StringIO("4\n"))
    code, err = _session(capsys, str(path), "--participant", "S01", "--out", str(tmp_path / "o"), "--headless",
                         "--no-audio")
    assert code == 2 and err.count("\n") == 1 and "stdin gives 1" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_check_warns_when_the_participants_leave_the_square_incomplete(named, tmp_path, capsys):
    path = _write(tmp_path, _plan(named))
    assert main(["session", str(path), "--check"]) == 0
    err = capsys.readouterr().err
    assert "3 participants use 3 of the 6 orders" in err and "multiple of 6" in err
    plan = parse_plan({**_plan(named), "participants": [f"P{k}" for k in range(6)]})
    assert square_warning(plan) is None


def test_the_session_files_audio_sets_the_speakers_volume_voice_and_playback(tmp_path):
    voice = tmp_path / "voice"
    shutil.copytree(SPEECH_DIR, voice)
    plan = parse_plan({"participants": ["P1"], "blocks": [{"name": "x", "routes": [0]}],
                       "audio": {"volume": 0.4, "voice": "voice", "playback": "slower"}}, base=tmp_path)
    assert (plan.audio.volume, plan.audio.voice, plan.audio.playback) == (0.4, str(voice), "slower")

    class Channel:
        def __init__(self):
            self.calls = []

        def set_volume(self, v):
            self.calls.append(("volume", v))

        def play(self, sound):
            self.calls.append(("play", sound))

    speaker = Speaker(enabled=False)
    speaker._channel, speaker.volume, speaker.voice = Channel(), plan.audio.volume, plan.audio.voice
    speaker._sounds[voice / "2_slower.wav"] = "sound"
    assert speaker.say(2, "slower") and speaker._channel.calls == [("volume", 0.4), ("play", "sound")]


# ----- what the participant sees --------------------------------------------------------------------------------
def _record_drawn(monkeypatch) -> list[str]:
    """Every string drawn in the window from now on (each font render), with the drives cut to 6 steps."""
    import pygame

    import pernav.play.loop as loop
    import pernav.play.screens as screens

    drawn: list[str] = []
    font = pygame.font.Font

    class Recording(font):
        def render(self, text, *args, **kwargs):
            drawn.append(str(text))
            return super().render(text, *args, **kwargs)

    monkeypatch.setattr(pygame.font, "Font", Recording)
    screens._font.cache_clear()
    run = loop.PlaySession.run
    monkeypatch.setattr(loop.PlaySession, "run", lambda self, max_steps=0: run(self, max_steps=6))  # short drives
    return drawn


@pytest.mark.parametrize("counters", [True, False])
def test_live_counters_are_drawn_only_in_a_block_that_shows_them(counters, tmp_path, monkeypatch):
    import pernav.play.screens as screens
    from pernav.play.controls import ScriptedControls

    drawn = _record_drawn(monkeypatch)
    plan = {"participants": ["S01"], "traffic": 0, "countdown": 0,
            "blocks": [{"name": "a", "routes": [0], "counters": counters}]}
    session = LabSession(load_plan(_write(tmp_path, plan)), "S01", tmp_path / "out", window=True,
                         controls=ScriptedControls, announce=lambda s: None, options=LabOptions(realtime=False))
    result = session.run()
    screens._font.cache_clear()
    assert result.finished and len(drawn) > 20
    shown = [s for s in drawn if any(w in s for w in ("collisions", "kerb strikes", "missed turns", "re-routes"))]
    assert bool(shown) == counters, shown[:3]


@pytest.mark.slow
def test_no_string_drawn_names_a_block_a_policy_or_the_cost(study, tmp_path, monkeypatch):
    import pernav.play.screens as screens
    from pernav.play.controls import ScriptedControls

    drawn = _record_drawn(monkeypatch)
    plan = {**_plan(study), "participants": ["S02"], "ssq": ["after_block"],
            "blocks": _plan(study)["blocks"][:2], "questionnaire": {"questions": [{"id": "q", "text": "How hard?",
                                                                                   "scale": [1, 7]}]}}
    session = LabSession(load_plan(_write(tmp_path, plan)), "S02", tmp_path / "out", window=True,
                         controls=ScriptedControls, answer=None, announce=lambda s: None,
                         options=LabOptions(realtime=False))
    monkeypatch.setattr("pernav.play.lab.ask_question", lambda view, text, scale, title=None: (
        screens.show_panel(view, [text], title=title), scale[0])[1])
    result = session.run()
    screens._font.cache_clear()
    assert result.finished and len(drawn) > 100
    assert any("Part 1 of 2" in s for s in drawn) and any("react about" in s for s in drawn)
    assert any("Consent" in s for s in drawn) and any("Instructions" in s for s in drawn)
    assert any("Part 2 of 2 comes next" in s for s in drawn)  # the break screen between the two blocks
    words = [*BLOCK_NAMES, *POLICY_NAMES, "cost"]
    assert not [s for s in drawn if any(w in s.lower() for w in words)]
    assert any("collisions" in s for s in drawn)  # the explore block's counters; the belief block shows none
