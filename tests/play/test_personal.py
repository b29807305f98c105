"""A study's model personalized to a person (`pernav personalize`, `pernav play --policy study`), headless: the
scripted bot drives, on the smallest study there is (one offline and one online round, adapt only)."""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import replace

import pytest
import torch
from play_helpers import PLANNER, K, model_study

from pernav.cli import main
from pernav.model.adapt import meta_parameters
from pernav.planner.factory import env_planning_config
from pernav.play.controls import ScriptedControls
from pernav.play.loop import PlaySession
from pernav.play.options import PlayError, PlayOptions
from pernav.play.personal import POLICY_NAMES, PersonalSession, study_policy
from pernav.play.sessions import SessionOptions, summary_markdown
from pernav.study.finished import FinishedStudy, StudyError, StudyPolicy
from pernav.trainer.drives import load_drive, read_metrics

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")


@pytest.fixture(scope="module")
def study_dir(tmp_path_factory):
    """A finished study in seconds (:func:`play_helpers.model_study`: adapt and adapt_speed, PLANNER, K)."""
    return model_study(tmp_path_factory)


@pytest.fixture(scope="module")
def session(study_dir, tmp_path_factory):
    """tau on route 0, then route 1 with both policies; two meta updates after each round."""
    lines: list[str] = []
    record = tmp_path_factory.mktemp("personal") / "me"
    options = SessionOptions(seed=0, record_dir=record, n_traffic=1, updates=2, progress=False)
    s = PersonalSession(study_dir, "Town1", [0, 1], announce=lines.append, options=options)
    return s, s.run(), lines


@pytest.mark.slow
def test_session_drives_tau_then_both_policies(session):
    s, result, _ = session
    assert not result.interrupted
    assert [(d["round"], d["label"]) for d in result.drives] == [(0, "tau"), (1, "drive1"), (1, "drive2")]
    assert result.drives[0]["policy"] == "explore"
    assert sorted(d["policy"] for d in result.drives[1:]) == ["adapted", "explore"]
    assert [d["policy"] for d in result.drives[1:]] == list(s.order[0])
    assert all(d["completed"] and not d["interrupted"] for d in result.drives)
    adapted = next(d for d in result.drives if d["policy"] == "adapted")
    assert adapted["adapted_on_round"] == 0  # planned with the parameters adapted on tau


@pytest.mark.slow
def test_drives_are_recorded_and_load(session):
    s, result, _ = session
    for d in result.drives:
        td = load_drive(d["file"])
        assert td.shape[0] == d["steps"] and td["history"].shape[-2] == K  # the study's history window
        meta = read_metrics(d["file"])
        assert meta["policy"] == d["policy"] and meta["round"] == d["round"]
        assert d["policy"] not in os.path.basename(d["file"])  # the file names do not tell either
    assert (s.record_dir / "model.pt").is_file()
    saved = torch.load(s.record_dir / "model.pt", weights_only=False)
    assert len(saved["trainer"]["members"]) == len(s.study.members)


@pytest.mark.slow
def test_summary_table_has_both_policies_in_range(session):
    s, result, _ = session
    summary = json.loads((s.record_dir / "summary.json").read_text())
    assert summary == json.loads(json.dumps(result.summary))
    assert set(summary["policies"]) == set(POLICY_NAMES)
    for row in summary["policies"].values():
        assert row["drives"] == 1 and 0 <= row["completion"] <= 1 and row["tracking_cost_mean"] >= 0
        assert row["vehicle_collisions"] >= 0 and row["kerb_strikes"] >= 0 and row["missed_turns"] >= 0
        assert 0 <= row["completed"] <= row["drives"]
    assert summary["paired_routes"] == 1
    costs = {d["policy"]: d["tracking_cost"] for d in result.drives[1:]}
    assert summary["paired_cost_difference_mean"] == pytest.approx(costs["adapted"] - costs["explore"], abs=0.01)
    table = (s.record_dir / "summary.md").read_text()
    assert "| adapted | 1 |" in table and "| explore | 1 |" in table


@pytest.mark.slow
def test_prompts_and_announcements_do_not_tell_the_policy(session):
    _, result, lines = session
    assert sum(line.startswith("Drive ") for line in lines) == len(result.drives)
    for line in lines:
        assert not any(word in line.lower() for word in ("explore", "adapt", "mpc", "study", "policy"))


@pytest.mark.slow
def test_meta_model_learns_and_adapted_parameters_differ(session, study_dir):
    s, _, _ = session
    study = FinishedStudy.open(study_dir).model("Town1")
    changed = [any(not torch.equal(m.model.state_dict()[k], state[k]) for k in state)
               for m, state in zip(s.trainer.members, study.members, strict=True)]
    assert all(changed)  # every member took the FTML updates on the person's drives
    assert len(s.meta_losses) == 2 * s.updates and all(torch.isfinite(torch.tensor(s.meta_losses)))
    assert s.adapted_on == 1  # re-adapted on the latest tau
    for m, p in zip(s.trainer.members, s.params, strict=True):
        meta = meta_parameters(m.model).detach()
        assert any(not torch.equal(meta[k], p[k]) for k in meta.keys(True, True))
    assert s.policy.planner.params is s.params


@pytest.mark.slow
def test_order_is_random_but_reproducible(study_dir):
    routes = list(range(10))
    orders = {seed: PersonalSession(study_dir, "Town1", routes, options=SessionOptions(seed=seed)).order
              for seed in range(4)}
    assert orders[0] == PersonalSession(study_dir, "Town1", routes, options=SessionOptions(seed=0)).order
    assert all(sorted(o) == sorted(POLICY_NAMES) for order in orders.values() for o in order)
    assert len({tuple(o) for o in orders[0]}) == 2  # both orders occur over the routes
    assert len({tuple(order) for order in orders.values()}) > 1  # and the seed changes them


@pytest.mark.slow
def test_adapted_policy_plans_on_the_studys_env(study_dir, session):
    tau = load_drive(session[1].drives[0]["file"])
    policy, info = study_policy(study_dir, "Town1", tau)
    assert info["adapted"] and info["adaptation"] == "U" and info["K"] == K and info["members"] == 2
    assert policy.env_config == {"adaptive_speed": False, **env_planning_config(PLANNER)}
    assert (policy.planner.horizon, policy.planner.advance) == (8, 4)
    # the drive takes K and the planning context from the policy
    play = PlaySession("Town1", 2, policy=policy, options=PlayOptions(n_traffic=1))
    assert play.nav.config["future_steps"] == 12 and play.env.transform.K == K
    result = play.run(max_steps=4)
    actions = result.trajectory["action"].reshape(-1)
    assert ((actions >= 0) & (actions < 7)).all() and result.metrics["policy"] == "study"
    unadapted, info0 = study_policy(study_dir, "Town1")
    assert not info0["adapted"]
    a, b = policy.planner.params[0], unadapted.planner.params[0]
    assert any(not torch.equal(a[k], b[k]) for k in a.keys(True, True))
    with pytest.raises(PlayError, match="history of 5 steps"):
        study_policy(study_dir, "Town1", PlaySession("Town1", 0, options=PlayOptions(n_traffic=0)).run(3).trajectory)


@pytest.mark.slow
def test_quitting_ends_the_session_with_what_was_driven(study_dir, tmp_path):
    made = []

    def controls():  # the person quits two seconds into their second drive
        made.append(ScriptedControls(quit_after=20 if made else None))
        return made[-1]

    record = tmp_path / "me"
    options = SessionOptions(record_dir=record, n_traffic=0, updates=1, progress=False)
    result = PersonalSession(study_dir, "Town1", [0, 1], controls=controls, options=options).run()
    assert result.interrupted and len(result.drives) == 2 and result.drives[1]["interrupted"]
    assert all(load_drive(d["file"]).shape[0] == d["steps"] for d in result.drives)
    summary = json.loads((record / "summary.json").read_text())
    assert summary["interrupted"] and all(r["drives"] == 0 for r in summary["policies"].values())
    assert "| adapted | 0 | - |" in summary_markdown(summary)


@pytest.mark.slow
def test_a_windowed_session_keeps_one_window_shows_the_wait_and_the_end(study_dir, monkeypatch):
    import pygame
    from play_helpers import watch_session_window

    from pernav.play.screens import STOPPED, WAITING

    seen = watch_session_window(monkeypatch)
    made = []

    def controls():  # the person stops two seconds into their second drive; the third: the end screen's
        made.append(ScriptedControls(quit_after=20 if len(made) == 1 else None))
        return made[-1]

    options = SessionOptions(n_traffic=0, updates=1, progress=False, window=True, hide_cost=True)
    result = PersonalSession(study_dir, "Town1", [0, 1], controls=controls, options=options).run()
    assert result.interrupted and len(result.drives) == 2 and len(made) == 3
    (first, open1), (second, open2) = seen["views"]
    assert first is second and first.window and open1 and open2  # one window, open across the drives
    assert not pygame.display.get_init()  # closed at the end
    panels = seen["panels"]
    assert panels[0] == [WAITING, "Drive 1 of 3: Town1 route 0"]
    learning = [p for p in panels if p[1].startswith("the navigation is learning from your drives")]
    assert learning and learning[0] == [WAITING, "the navigation is learning from your drives: about 4 s left"]
    assert panels[-1] == [STOPPED, "1 of 3 drives driven; what you drove is kept.", "Press Enter to close"]
    assert not any("cost" in line for p in panels for line in p)


@pytest.mark.slow
def test_bad_study_folders(study_dir, tmp_path):
    with pytest.raises(StudyError, match="no study folder"):
        FinishedStudy.open(tmp_path / "none")
    with pytest.raises(PlayError, match="no study folder"):  # a session says the study's words as its own
        PersonalSession(tmp_path / "none", "Town1", [0, 1])
    unfinished = tmp_path / "unfinished"
    shutil.copytree(study_dir, unfinished)
    (unfinished / "results.json").unlink()
    with pytest.raises(StudyError, match="not finished"):
        FinishedStudy.open(unfinished)
    with pytest.raises(StudyError, match="not in the study"):
        FinishedStudy.open(study_dir).model("Town1", learner="sysid")
    with pytest.raises(PlayError, match="not in the study"):
        PersonalSession(study_dir, "Town1", [0, 1], options=SessionOptions(learner="sysid"))
    taken = tmp_path / "taken"
    taken.mkdir()
    (taken / "summary.json").write_text("{}")
    with pytest.raises(PlayError, match="already holds"):
        PersonalSession(study_dir, "Town1", [0, 1], options=SessionOptions(record_dir=taken))
    assert isinstance(study_policy(study_dir, "Town1")[0], StudyPolicy)


def _exits_2_and_writes_nothing(command: str, args: list[str], study_dir, tmp_path, capsys) -> None:
    """``pernav COMMAND ARGS`` (``{missing}`` and ``{study}`` filled in) exits 2 with one error line and records
    nothing."""
    rec = tmp_path / "rec"
    args = [a.format(missing=tmp_path / "missing", study=study_dir) for a in args]
    assert main([command, *args, "--headless", "--no-audio", "--record", str(rec)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"pernav {command}: error:") and err.count("\n") == 1 and "Traceback" not in err
    assert not rec.exists()


@pytest.mark.parametrize("args", [
    ["--study", "{missing}", "--town", "Town1", "--routes", "0", "1"],
    ["--study", "{study}", "--town", "Town2", "--routes", "0", "1"],  # a town the study did not run
    ["--study", "{study}", "--town", "Town1", "--routes", "0", "12"],
    ["--study", "{study}", "--town", "Town1", "--routes", "0"],
    ["--study", "{study}", "--town", "Town9", "--routes", "0", "1"],
    ["--study", "{study}", "--town", "Town1", "--routes", "0", "1", "--updates", "-1"],
    ["--study", "{study}", "--town", "Town1", "--routes", "0", "1", "--seed", "-1"],
    ["--study", "{study}", "--town", "Town1", "--routes", "0", "1", "--learner", "hindsight"],
    ["--study", "{study}", "--town", "Town1", "--routes", "0", "1", "--learner", "sysid"],  # not in the study
])
@pytest.mark.slow
def test_cli_personalize_bad_input_exits_2_and_writes_nothing(args, study_dir, tmp_path, capsys):
    _exits_2_and_writes_nothing("personalize", args, study_dir, tmp_path, capsys)


@pytest.mark.parametrize("args", [
    ["--policy", "study"], ["--policy", "study", "--study", "{missing}"],
    ["--study", "{study}", "--tau", "{missing}"],  # --tau goes with --policy study
    ["--policy", "study", "--study", "{study}", "--town", "Town2"],
    ["--policy", "study", "--study", "{study}", "--tau", "{missing}"],
    ["--policy", "study", "--study", "{study}", "--tau", "{study}/study.json"],
    ["--policy", "study", "--study", "{study}", "--playback", "slower"],
    ["--learner", "adapt"],  # --learner goes with --policy study
    ["--policy", "study", "--study", "{study}", "--learner", "nope"],
])
@pytest.mark.slow
def test_cli_play_study_bad_input_exits_2_and_writes_nothing(args, study_dir, tmp_path, capsys):
    _exits_2_and_writes_nothing("play", args, study_dir, tmp_path, capsys)


@pytest.mark.slow
def test_cli_personalize_then_play_with_the_recorded_tau(study_dir, tmp_path, capsys):
    rec = tmp_path / "me"
    assert main(["personalize", "--study", str(study_dir), "--town", "Town1", "--routes", "0", "1", "--headless",
                 "--no-audio", "--traffic", "1", "--updates", "1", "--record", str(rec)]) == 0
    out = capsys.readouterr().out
    assert "| adapted | 1 |" in out and "| explore | 1 |" in out and f"recorded: {rec}" in out
    assert len(list(rec.glob("*.pt"))) == 4  # three drives and the model
    tau = rec / "round00-route0-tau.pt"
    play = tmp_path / "play"
    assert main(["play", "--policy", "study", "--study", str(study_dir), "--tau", str(tau), "--route", "2",
                 "--headless", "--no-audio", "--traffic", "1", "--record", str(play), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["policy"] == "study" and out["study"]["adapted"] and out["study"]["K"] == K
    assert load_drive(out["record"]).shape[0] == out["steps"]


@pytest.mark.slow
def test_adapt_speed_chooses_playback_and_learns_in_its_action_space(study_dir, tmp_path, capsys):
    options = SessionOptions(seed=0, record_dir=tmp_path / "me", n_traffic=1, updates=1, learner="adapt_speed",
                             progress=False)
    s = PersonalSession(study_dir, "Town1", [0, 1], options=options)
    result = s.run()
    assert not result.interrupted and result.summary["learner"] == "adapt_speed"
    drives = {d["policy"]: load_drive(d["file"]) for d in result.drives[1:]}
    state = drives["explore"]["observation"].shape[-1]
    assert drives["adapted"]["history"].shape[-1] == state + 21  # the adapted drive chose instruction and speed
    assert drives["explore"]["history"].shape[-1] == state + 7  # explore's drive spoke as explore does
    data, tau = s.buffers.data(1), s.buffers.tau(1)  # the round's data in the learner's 21-action space
    assert data["history"].shape[-1] == state + 21 and data.shape[0] == sum(d.shape[0] for d in drives.values())
    assert ((data["action"] >= 0) & (data["action"] < 21)).all()
    assert torch.equal(tau["action"].reshape(-1), drives["explore"]["action"].long().reshape(-1) * 3 + 1)
    assert s.policy.env_config["adaptive_speed"] and s.policy.n_actions == 21
    out = tmp_path / "play"
    assert main(["play", "--policy", "study", "--study", str(study_dir), "--learner", "adapt_speed", "--route", "2",
                 "--tau", str(result.drives[0]["file"]), "--headless", "--no-audio", "--traffic", "1",
                 "--record", str(out), "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert shown["study"]["learner"] == "adapt_speed" and shown["study"]["env_config"]["adaptive_speed"]
    assert load_drive(shown["record"])["history"].shape[-1] == state + 21


@pytest.mark.slow
def test_a_sysid_session_trains_plainly_and_plans_unadapted(tmp_path, monkeypatch):
    from pernav.study import preset, run_study

    cfg = preset("smoke")
    cfg.methods, cfg.schedule, cfg.calibration, cfg.train.warm_updates = ["sysid"], cfg.schedule[:2], 0, 10
    run_study(cfg, tmp_path / "study", report=False)
    options = SessionOptions(n_traffic=0, updates=2, learner="sysid", progress=False)
    s = PersonalSession(tmp_path / "study", "Town1", [0, 1], options=options)
    flags: list[bool] = []
    train = s.trainer.train
    monkeypatch.setattr(s.trainer, "train", lambda n, meta: flags.append(meta) or train(n, meta=meta))
    assert not s.run().interrupted
    assert flags == [False] * 4  # two plain updates after each of the two rounds, as the study trains sysid
    for member, params in zip(s.trainer.members, s.params, strict=True):  # planned with the model itself
        meta = meta_parameters(member.model).detach()
        assert all(torch.equal(meta[k], params[k]) for k in meta.keys(True, True))

# ----- resume, Ctrl-C, checks before anyone drives --------------------------------------------------------
class Killed(BaseException):
    """The process killed (nothing after it runs: no summary, no clean-up)."""


@pytest.mark.slow
def test_a_session_killed_after_drive_2_resumes_with_its_tau_and_drives(session, study_dir, tmp_path):
    full, full_result, _ = session  # the same session driven without a break
    record = tmp_path / "me"
    made = []

    def controls():
        made.append(ScriptedControls())
        if len(made) == 3:
            def killed() -> None:
                raise Killed
            made[-1].poll = killed
        return made[-1]

    options = SessionOptions(seed=0, record_dir=record, n_traffic=1, updates=2, progress=False)
    first = PersonalSession(study_dir, "Town1", [0, 1], controls=controls, options=options)
    with pytest.raises(Killed):
        first.run()
    assert not (record / "summary.json").exists()  # killed: no summary
    tau_file = record / "round00-route0-tau.pt"
    tau_bytes, second_bytes = tau_file.read_bytes(), (record / "round01-route1-drive1.pt").read_bytes()
    with pytest.raises(PlayError, match="already holds a personalization session.*--resume"):
        PersonalSession(study_dir, "Town1", [0, 1], options=replace(options, progress=True))
    with pytest.raises(PlayError, match="was run with seed 0, not 1"):
        PersonalSession(study_dir, "Town1", [0, 1], options=replace(options, seed=1, resume=True))
    lines: list[str] = []
    resumed = PersonalSession(study_dir, "Town1", [0, 1], announce=lines.append, options=replace(options, resume=True))
    assert [d["label"] for d in resumed.drives] == ["tau", "drive1"] and resumed.learned == [0]
    result = resumed.run()
    assert not result.interrupted and [line for line in lines if line.startswith("Drive")] == [
        "Drive 3 of 3: Town1 route 1"]  # only the drive not yet driven
    assert tau_file.read_bytes() == tau_bytes and (record / "round01-route1-drive1.pt").read_bytes() == second_bytes
    assert [(d["round"], d["label"]) for d in result.drives] == [(0, "tau"), (1, "drive1"), (1, "drive2")]
    # the same tau, drives and model as the session driven without a break
    for mine, theirs in zip(result.drives, full_result.drives, strict=True):
        assert mine["tracking_cost"] == theirs["tracking_cost"] and mine["policy"] == theirs["policy"]
    for a, b in zip(resumed.trainer.members, full.trainer.members, strict=True):
        for key, value in a.model.state_dict().items():
            torch.testing.assert_close(value, b.model.state_dict()[key])
    assert result.summary["resumed"] and json.loads((record / "summary.json").read_text())["paired_routes"] == 1
    with pytest.raises(PlayError, match="is complete; nothing to resume"):
        PersonalSession(study_dir, "Town1", [0, 1], options=replace(options, resume=True, progress=True))


@pytest.mark.slow
def test_cli_personalize_ctrl_c_keeps_the_drive_in_progress_and_exits_130(study_dir, tmp_path, capsys, monkeypatch):
    def poll(self) -> None:  # Ctrl-C two seconds into the first drive
        if self.frames >= 25:
            raise KeyboardInterrupt

    monkeypatch.setattr(ScriptedControls, "poll", poll)
    rec = tmp_path / "me"
    base = ["personalize", "--study", str(study_dir), "--town", "Town1", "--routes", "0", "1", "--headless",
            "--no-audio", "--traffic", "0", "--updates", "1", "--record", str(rec)]
    assert main(base) == 130
    captured = capsys.readouterr()
    assert "interrupted (Ctrl-C)" in captured.err and "--resume" in captured.out
    stopped = rec / "round00-route0-tau-stopped.pt"
    assert read_metrics(stopped)["interrupted"] and read_metrics(stopped)["stopped_by"] == "ctrl-c"
    assert load_drive(stopped).shape[0] == 2
    monkeypatch.undo()
    assert main([*base, "--resume"]) == 0  # the stopped tau is driven again, whole
    assert "resuming" in capsys.readouterr().out
    assert read_metrics(rec / "round00-route0-tau.pt")["completed"] and stopped.is_file()


@pytest.mark.parametrize("args,words", [
    (["--resume"], "--resume needs --record"),
    (["--record", "{tmp}/empty", "--resume"], "holds no personalization session"),
    (["--record", "{tmp}/file/me"], "cannot be written"),
    (["--countdown", "-1", "--record", "{tmp}/me"], "--countdown"),
])
@pytest.mark.slow
def test_cli_personalize_refusals_before_anyone_drives(args, words, study_dir, tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    (tmp_path / "empty").mkdir()
    args = [a.format(tmp=tmp_path) for a in args]
    assert main(["personalize", "--study", str(study_dir), "--town", "Town1", "--routes", "0", "1", "--headless",
                 "--no-audio", *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pernav personalize: error:") and words in err and err.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty", "file"] and not any((tmp_path / "empty").iterdir())


@pytest.mark.slow
def test_cli_play_refuses_a_tau_of_another_town_or_history(study_dir, tmp_path, capsys):
    from pernav.trainer.drives import save_drive

    other = PlaySession("Town2", 0, options=PlayOptions(n_traffic=0, K=K)).run(max_steps=3)
    town2 = save_drive(other.trajectory, other.metrics, tmp_path, "town2")
    five = PlaySession("Town1", 0, options=PlayOptions(n_traffic=0, K=5)).run(max_steps=3)
    k5 = save_drive(five.trajectory, five.metrics, tmp_path, "k5")
    base = ["play", "--policy", "study", "--study", str(study_dir), "--headless", "--no-audio",
            "--record", str(tmp_path / "rec")]
    for tau, words in ((town2, "was recorded in Town2; this drive is in Town1"),
                       (k5, f"history of 5 steps: the study's model reads {K}")):
        assert main([*base, "--tau", str(tau)]) == 2
        err = capsys.readouterr().err
        assert words in err and err.count("\n") == 1 and "Traceback" not in err
    assert main(["play", "--study", str(study_dir), "--history", "5", "--headless", "--no-audio"]) == 2
    err = capsys.readouterr().err
    assert f"reads a history of {K} steps" in err and "--history 5" in err
    assert not (tmp_path / "rec").exists()


@pytest.mark.slow
def test_cli_play_for_a_study_records_its_history(study_dir, tmp_path, capsys):
    assert main(["play", "--study", str(study_dir), "--headless", "--no-audio", "--traffic", "0", "--record",
                 str(tmp_path / "rec"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert load_drive(out["record"])["history"].shape[-2] == K and out["policy"] == "explore"
