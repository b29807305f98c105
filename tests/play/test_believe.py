"""`pernav personalize --learner belief`, headless: the scripted bot drives, on a study that ran the learners that
re-time explore's rule (one offline and one online round, four offline drivers)."""

from __future__ import annotations

import json
import os

import pytest
import torch
from play_helpers import retimed_study

from pernav.cli import main
from pernav.learners.belief import ReactionBelief
from pernav.play.believe import BeliefSession, prompt_lead, session_class
from pernav.play.options import PlayError
from pernav.play.personal import PersonalSession
from pernav.play.sessions import SessionOptions, belief_markdown
from pernav.trainer.drives import load_drive

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")


@pytest.fixture(scope="module")
def belief_study(tmp_path_factory):
    """explore, timing and belief (:func:`play_helpers.retimed_study`; the belief learner is the same without
    timing)."""
    return retimed_study(tmp_path_factory)


@pytest.fixture(scope="module")
def session(belief_study, tmp_path_factory):
    lines: list[str] = []
    record = tmp_path_factory.mktemp("believe") / "me"
    options = SessionOptions(seed=0, record_dir=record, n_traffic=1)
    s = BeliefSession(belief_study, "Town1", [0, 1, 2], user="user3", announce=lines.append, options=options)
    return s, s.run(), lines, record


@pytest.mark.slow
def test_each_whole_drive_updates_the_belief_and_tells_the_person(session):
    s, result, lines, record = session
    assert [d["policy"] for d in result.drives] == ["explore", "belief", "belief"] and not result.interrupted
    beliefs = result.summary["beliefs"]
    assert [b["after_drive"] for b in beliefs] == [None, 1, 2, 3]
    # the evidence accumulates: more answers read, and the interval does not widen as drives add up
    assert beliefs[0]["answers"] == 0 < beliefs[1]["answers"] < beliefs[3]["answers"]
    widths = [b["interval"][1] - b["interval"][0] for b in beliefs]
    assert widths[3] < widths[0]
    assert all(b["interval"][0] <= b["reaction_time"] <= b["interval"][1] for b in beliefs)
    told = [line for line in lines if "your reaction time" in line]
    assert len(told) == 3 and all("90 % interval" in line for line in told)
    assert sum("'turn' prompt at 50 km/h" in line for line in lines) == 3


@pytest.mark.slow
def test_the_session_keeps_its_drives_and_the_posterior(session):
    s, result, lines, record = session
    assert all(load_drive(d["file"])["next", "frames"].shape[-2:] == (10, 5) for d in result.drives)
    saved = torch.load(record / "belief.pt", weights_only=False)
    belief = ReactionBelief.from_state_dict(saved["belief"])
    assert round(belief.mean_reaction(), 3) == result.summary["beliefs"][-1]["reaction_time"]
    assert json.loads((record / "summary.json").read_text())["beliefs"] == result.summary["beliefs"]
    assert "| drive 3 |" in (record / "summary.md").read_text()


@pytest.mark.slow
def test_hide_cost_keeps_the_cost_out_of_what_the_person_is_told(belief_study):
    lines: list[str] = []
    options = SessionOptions(n_traffic=0, hide_cost=True)
    BeliefSession(belief_study, "Town1", [0, 1], announce=lines.append, options=options).run()
    assert any("arrived" in line or "did not arrive" in line for line in lines)
    assert not any("cost" in line for line in lines)


def test_the_prompts_follow_the_belief():
    assert prompt_lead({}) < prompt_lead({"reaction_time": 2.0}) < prompt_lead({"reaction_time": 3.0})
    assert session_class("belief") is BeliefSession and session_class("adapt") is PersonalSession
    table = belief_markdown({"beliefs": [{"after_drive": 2, "reaction_time": 1.5, "interval": [1.1, 2.0],
                                          "answers": 12, "turn_lead_s": 3.04}]})
    assert table.splitlines()[2] == "| drive 2 | 1.50 s | 1.10-2.00 s | 12 | 3.0 s |"


@pytest.mark.slow
def test_cli_personalize_with_the_belief_learner(belief_study, tmp_path, capsys):
    rec = tmp_path / "me"
    assert main(["personalize", "--study", str(belief_study), "--town", "Town1", "--routes", "0", "1", "--headless",
                 "--no-audio", "--traffic", "0", "--record", str(rec), "--learner", "belief"]) == 0
    out = capsys.readouterr().out
    assert out.count("your reaction time, as the navigation reads it") == 2 and "| after | reaction time" in out
    assert (rec / "belief.pt").is_file() and (rec / "summary.md").is_file()


@pytest.mark.parametrize("args,words", [
    (["--resume", "--record", "{tmp}/me"], "--resume goes with a model-based learner"),
    (["--updates", "3"], "--updates goes with a model-based learner"),
    (["--learner", "belief2"], "choose one of"),
])
@pytest.mark.slow
def test_cli_belief_refusals_before_anyone_drives(args, words, belief_study, tmp_path, capsys):
    args = [a.format(tmp=tmp_path) for a in args]
    learner = [] if "--learner" in args else ["--learner", "belief"]
    assert main(["personalize", "--study", str(belief_study), "--town", "Town1", "--routes", "0", "1", "--headless",
                 "--no-audio", *learner, *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pernav personalize: error:") and words in err and err.count("\n") == 1
    assert not any(tmp_path.iterdir())


@pytest.mark.slow
def test_a_study_without_the_belief_learner_is_refused_by_name(belief_study, tmp_path):
    import shutil

    from pernav.study.checkpoints import file_sha256

    other = tmp_path / "study"
    shutil.copytree(belief_study, other)
    folder = other / "checkpoints" / "Town1"
    manifest = json.loads((folder / "manifest.json").read_text())
    state = folder / manifest["folder"] / "state.pt"
    data = torch.load(state, weights_only=False)
    del data["state"]["belief_model"]  # as a study that did not run it
    torch.save(data, state)
    manifest["files"]["state.pt"] = file_sha256(state)
    (folder / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(PlayError, match="did not run the belief learner"):
        BeliefSession(other, "Town1", [0, 1])


@pytest.mark.slow
def test_cli_hide_cost_prints_no_cost_in_the_terminal(belief_study, tmp_path, capsys):
    rec = tmp_path / "me"
    assert main(["personalize", "--study", str(belief_study), "--town", "Town1", "--routes", "0", "1", "--headless",
                 "--no-audio", "--traffic", "0", "--record", str(rec), "--learner", "belief", "--hide-cost"]) == 0
    out = capsys.readouterr().out
    assert "cost" not in out.replace(str(rec), "") and "your reaction time" in out
    assert "tracking cost" in (rec / "summary.md").read_text()


@pytest.mark.slow
def test_a_windowed_belief_session_keeps_one_window_and_ends_with_thanks(belief_study, monkeypatch):
    import pygame
    from play_helpers import watch_session_window

    from pernav.play.screens import CLOSING, FINISHED, WAITING

    seen = watch_session_window(monkeypatch)
    options = SessionOptions(n_traffic=0, window=True, hide_cost=True)
    result = BeliefSession(belief_study, "Town1", [0, 1], options=options).run()
    assert not result.interrupted and len(result.drives) == 2
    (first, _), (second, _) = seen["views"]
    assert first is second and first.window and not pygame.display.get_init()
    panels = seen["panels"]
    assert [WAITING, "the navigation is reading your answers: about 2 s left"] in panels
    assert [p[0] for p in panels].count(CLOSING) == 1  # reading the last drive: no drive follows
    assert panels[-1] == [FINISHED, "You drove all 2 drives.", "Press Enter to close"]
    assert not any("cost" in line for p in panels for line in p)


@pytest.mark.slow
def test_a_folder_holding_a_belief_session_is_refused_without_suggesting_resume(session, belief_study):
    # a belief session is not resumed (its drives and belief.pt stay as driven): its refusal must not point to --resume
    *_, record = session
    with pytest.raises(PlayError, match="already holds a personalization session") as refused:
        BeliefSession(belief_study, "Town1", [0, 1], options=SessionOptions(seed=0, record_dir=record, n_traffic=1))
    assert "--resume" not in str(refused.value) and "not resumed" in str(refused.value)
