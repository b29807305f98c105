"""A schedule entry takes recorded drives (a person's, ``pernav play --record``) as its round's data, so a
study mixes people and simulated drivers; bad drives are one-line errors naming the entry and the file (exit 2)."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest
import torch
from navigation_helpers import TIME_LIMIT, shared_folder
from study_helpers import kill_then_resume

from pernav.cli import main
from pernav.play.loop import PlaySession
from pernav.play.options import PlayOptions
from pernav.study import ScheduleError, load_schedule, preset
from pernav.trainer.buffers import RoundBuffers
from pernav.trainer.drives import load_drive, read_metrics, save_drive

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

METHODS = ["explore", "sysid", "adapt", "adapt_speed", "hindsight"]


def _record_drives(folder: Path) -> Path:
    """Two short headless drives of Town1 by the scripted bot (routes 0 and 1), saved as ``pernav play`` does."""
    for name, route, steps in (("alice_0", 0, 30), ("alice_1", 1, 24)):
        result = PlaySession("Town1", route, options=PlayOptions(n_traffic=2, seed=route)).run(max_steps=steps)
        save_drive(result.trajectory, result.metrics, folder / "drives", name)
    return folder


@pytest.fixture(scope="module")
def drives(tmp_path_factory) -> Path:
    """This worker's own copy of the recorded drives (its tests write schedules beside them)."""
    return _record_drives(tmp_path_factory.mktemp("recorded"))


def _schedule(folder: Path, rows: list[dict], name: str = "schedule.json") -> Path:
    path = folder / name
    path.write_text(json.dumps(rows))
    return path


MIXED = [
    {"label": "Offline 0", "phase": "offline", "driver": "user1"},
    {"label": "Person warm-up", "phase": "offline", "drives": ["drives/alice_1.pt"]},
    {"label": "Online 0", "phase": "online", "driver": "user1", "vehicle": "cybertruck"},
    # the second drive named first: it is the round's tau; the glob adds the other one (and not the first twice)
    {"label": "Person", "phase": "online", "drives": ["drives/alice_1.pt", "drives/alice_*.pt"]},
    # no simulated round after "Person": the kill-and-resume test's resumed rounds ("Online 0", "Person") already
    # cover a simulated round after a person's, and each round is some 25 s of the test suite
]


def test_drives_resolve_relative_to_the_schedule_file_in_order(drives):
    entries = load_schedule(_schedule(drives, MIXED))
    person = entries[3]
    names = [Path(p).name for p in person.drives]
    assert names == ["alice_1.pt", "alice_0.pt"] and person.driver is None
    assert person.drives_in("Town1") == list(person.drives) and person.drives_in("Town2") == []
    assert person.user() == {"name": "recorded", "drives": names, "profile": None, "context": None}
    as_dict = person.to_dict()["drives"]
    assert [Path(d["file"]).name for d in as_dict] == names and all(len(d["sha256"]) == 64 for d in as_dict)
    assert "drives" not in entries[0].to_dict()  # a study without drives keeps its fingerprint


@pytest.fixture(scope="module")
def mixed_study(tmp_path_factory) -> Path:
    """The smoke study of the MIXED schedule (recorded and simulated rounds; episodes cut at TIME_LIMIT), run once per test
    session for the tests below (on its own copy of the drives, which are the same: the bot and the world are seeded)."""

    def build(folder: Path) -> None:
        schedule = _schedule(_record_drives(folder), MIXED)
        assert main(["study", "--preset", "smoke", "--out", str(folder / "study"), "--schedule", str(schedule),
                     "--methods", *METHODS, "--time-limit-factor", str(TIME_LIMIT)]) == 0

    return shared_folder(tmp_path_factory, "mixed_study", build) / "study"


@pytest.mark.slow
def test_a_study_learns_from_recorded_and_simulated_drives(mixed_study, drives, capsys):
    out = mixed_study
    results = json.loads((out / "results.json").read_text())
    iterations = {it["label"]: it for it in results["iterations"]}
    assert set(iterations["Online 0"]["towns"]["Town1"]) == set(METHODS)  # simulated rounds: evaluated
    for label in ("Person warm-up", "Person"):  # recorded rounds: data only, no episodes
        assert iterations[label]["towns"]["Town1"] == {} and iterations[label]["user"]["name"] == "recorded"
    regret = results["regret"]["Town1"]
    assert "Person" in regret["labels"] and regret["adaptation"]["Person"]["adapted"] > 0  # held out: alice_0
    assert results["summary"]["Town1"]["adapt"]["rounds"] == 1  # the simulated online rounds
    assert (out / "report.md").exists() and (out / "figures" / "Town1_cost.png").exists()

    last = sorted((out / "checkpoints" / "Town1").glob("entry_*"))[-1]
    first, second = load_drive(drives / "drives" / "alice_0.pt"), load_drive(drives / "drives" / "alice_1.pt")
    for name in ("sysid", "adapt"):
        buffers = RoundBuffers.load(last / f"buffers_{name}")
        assert torch.equal(buffers.tau(1)["observation"], second["observation"])  # the offline person's round
        assert buffers.data(1).shape[0] == second.shape[0]
        data, tau = buffers.data(3), buffers.tau(3)  # the online person's round: both drives, alice_1 its tau
        assert torch.equal(tau["observation"], second["observation"]) and torch.equal(tau["action"], second["action"])
        assert data.shape[0] == first.shape[0] + second.shape[0]
        assert set(data.keys()) == set(buffers.data(2).keys())  # the same keys as a simulated round's
        held_out = data[data["traj"] != int(tau["traj"][0])]
        assert torch.equal(held_out["observation"], first["observation"])
        assert torch.equal(held_out["history"], first["history"])
        assert torch.equal(held_out["next", "observation"], first["next", "observation"])
    speed = RoundBuffers.load(last / "buffers_adapt_speed").tau(3)  # re-encoded in the 21-action space
    assert torch.equal(speed["action"], second["action"].long().reshape(-1) * 3 + 1)
    capsys.readouterr()


@pytest.mark.slow
def test_a_study_with_recorded_drives_killed_after_a_person_resumes_to_the_same_results(mixed_study, drives, tmp_path):
    """Killed once the offline person's round is checkpointed, then resumed: the online person's round and the
    simulated rounds after it give what the uninterrupted study gave."""
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "pernav.cli", "study", "--preset", "smoke", "--out", str(out), "--schedule",
           str(_schedule(drives, MIXED)), "--methods", *METHODS, "--time-limit-factor", str(TIME_LIMIT)]
    got = kill_then_resume(cmd, out, "Town1", index=1)  # entry 1 is "Person warm-up" (recorded, offline)
    reference = json.loads((mixed_study / "results.json").read_text())
    for it_got, it_ref in zip(got["iterations"], reference["iterations"], strict=True):
        assert it_got["label"] == it_ref["label"]
        assert it_got["towns"] == it_ref["towns"], it_got["label"]
    assert got["regret"]["Town1"]["adaptation"] == reference["regret"]["Town1"]["adaptation"]


def _check_exits_2(args: list[str], words: list[str], capsys, out: Path) -> None:
    assert main(["study", "--preset", "smoke", "--out", str(out), *args]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    for w in words:
        assert w in err, (w, err)
    assert not out.exists()


def _person(**fields) -> list[dict]:
    """A schedule whose entry 2 is a person's online round (beside simulated rounds in every town)."""
    return [MIXED[0], MIXED[2], {"label": "Person", "phase": "online", "drives": ["drives/alice_0.pt"], **fields}]


def test_bad_recorded_entries_name_the_entry_and_the_file_and_exit_2(drives, tmp_path, capsys):
    out = tmp_path / "study"
    missing = _schedule(drives, _person(drives=["drives/bob.pt"]), "m.json")
    _check_exits_2(["--schedule", str(missing)], ["entry 2 ('Person')", "'drives'", "bob.pt", "does not exist"],
                   capsys, out)
    no_match = _schedule(drives, _person(drives=["drives/carol_*.pt"]), "g.json")
    _check_exits_2(["--schedule", str(no_match)], ["entry 2", "carol_*.pt", "no file matches"], capsys, out)
    # the study's model reads 10 steps of history: a drive recorded with K = 5 does not fit it
    fine = _schedule(drives, _person(), "ok.json")
    _check_exits_2(["--schedule", str(fine), "--train-option", "K=10"],
                   ["entry 2 ('Person')", "alice_0.pt", "K = 5", "K = 10"], capsys, out)
    _check_exits_2(["--schedule", str(fine), "--towns", "Town2"],  # a Town1 drive in a Town2 study
                   ["entry 2 ('Person')", "alice_0.pt", "of Town1", "study's towns (Town2)"], capsys, out)
    other_town = _schedule(drives, _person(towns=["Town2"]), "t.json")
    with pytest.raises(ScheduleError, match=r"entry 2 \('Person'\).*alice_0\.pt.*of Town1.*entry's towns \(Town2\)"):
        cfg = preset("smoke")
        cfg.towns, cfg.schedule = ["Town1", "Town2"], load_schedule(other_town)
        cfg.validate()
    with pytest.raises(ScheduleError, match="runs in Town2 but none of its drives is of Town2"):
        cfg = preset("smoke")
        cfg.towns, cfg.schedule = ["Town1", "Town2"], load_schedule(fine)
        cfg.validate()
    load_schedule(fine)  # and the good one is fine


def test_drives_of_the_wrong_format_are_refused(drives, tmp_path):
    folder = tmp_path / "bad"
    drive = load_drive(drives / "drives" / "alice_0.pt")
    metrics = read_metrics(drives / "drives" / "alice_0.pt")
    save_drive(drive.exclude("route_ahead"), metrics, folder, "no_route")
    save_drive(drive.clone().update({"action": drive["action"] + 7}), metrics, folder, "fast")  # 21 actions: playback
    wide = drive.clone()
    wide["history"] = torch.cat([wide["history"], wide["history"][..., :1]], -1)
    save_drive(wide, metrics, folder, "wide")
    torch.save({"weights": torch.zeros(3)}, folder / "model.pt")
    (folder / "model.json").write_text("{}")
    for name, words in (("no_route", "has no 'route_ahead'"), ("fast", "outside the study's 7 instructions"),
                        ("wide", "history of (5, 22)"), ("model", "is not a pernav drive")):
        with pytest.raises(ScheduleError) as err:
            load_schedule(_schedule(folder, _person(drives=[f"{name}.pt"]), f"schedule_{name}.json"))
        assert "entry 2 ('Person')" in str(err.value) and f"{name}.pt" in str(err.value) and words in str(err.value)
    with pytest.raises(ScheduleError, match="give 'drives' or a simulated 'driver'"):
        load_schedule(_schedule(drives, _person(driver="user1"), "both.json"))
    with pytest.raises(ScheduleError, match="field 'vehicle': an entry with 'drives'"):
        load_schedule(_schedule(drives, _person(vehicle="camaro"), "vehicle.json"))
    with pytest.raises(ScheduleError, match="non-empty list of drive files"):
        load_schedule(_schedule(drives, _person(drives=[]), "empty.json"))
