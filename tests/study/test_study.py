"""The online study: smoke preset schema, determinism across workers, resume, bad input."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from study_helpers import mini_config, mini_reference, mini_study, smoke_study, without_wall_time

from pernav.cli import main
from pernav.study import ScheduleError, load_schedule, paper_schedule, parse_schedule, preset, run_study

METHOD_KEYS = {"tracking_cost", "collisions", "vehicle_collisions", "edge_strikes", "completion", "episodes"}
SUMMARY_KEYS = {"tracking_cost_mean", "collisions_mean", "collisions_std", "completion_mean"}


@pytest.fixture(scope="module")
def two_workers(tmp_path_factory) -> tuple[Path, dict]:
    """study_helpers.two_towns on a pool of two workers (run once per session: the shared smoke study)."""
    out = smoke_study(tmp_path_factory)
    return out, json.loads((out / "results.json").read_text())


@pytest.mark.slow
def test_smoke_results_match_the_schema(two_workers):
    out, on_disk = two_workers
    assert {"config", "iterations", "summary"} <= set(on_disk)
    labels = [it["label"] for it in on_disk["iterations"]]
    assert labels == ["Offline 0", "Online 0", "Online 8"]
    assert [sorted(it["towns"]) for it in on_disk["iterations"]] == [["Town1", "Town2"]] * 2 + [["Town1"]]
    for it in on_disk["iterations"]:
        assert it["phase"] in ("offline", "online")
        assert {"name", "profile", "context"} <= set(it["user"])
        assert set(it["user"]["context"]) == {"vehicle", "camera", "visual", "equipment"}
        for town, methods in it["towns"].items():
            assert town in ("Town1", "Town2")
            expected = {"explore"} if it["phase"] == "offline" else set(preset("smoke").methods)
            assert set(methods) == expected
            for figures in methods.values():
                assert METHOD_KEYS <= set(figures)
                assert 0.0 <= figures["completion"] <= 1.0
                assert figures["collisions"] == figures["vehicle_collisions"] + figures["edge_strikes"]
                assert figures["tracking_cost"] >= 0
    for town, rounds in (("Town1", 2), ("Town2", 1)):
        assert set(on_disk["summary"][town]) == set(preset("smoke").methods), town
        for method, s in on_disk["summary"][town].items():
            assert SUMMARY_KEYS <= set(s) and s["rounds"] == rounds, (town, method)
    assert (out / "report.md").read_text().startswith("# pernav study")
    assert (out / "figures" / "Town1_cost.png").stat().st_size > 1000
    assert (out / "figures" / "Town1_regret.png").exists()
    assert list((out / "logs").rglob("*.csv")), "scalar logs through TorchRL's CSVLogger"
    for town, rounds in (("Town1", ["Online 0", "Online 8"]), ("Town2", ["Online 0"])):  # adapt_driver's FTML regret
        reg = on_disk["regret"][town]["adapt_driver"]
        assert reg["labels"] and set(reg["labels"]) <= set(rounds) and len(reg["loss_regret"]) == len(reg["labels"])
        assert all(math.isfinite(x) for x in reg["loss_regret"]) and reg["hindsight_prior"]["mean"]


@pytest.mark.slow
def test_a_towns_results_are_the_same_in_one_process_and_in_a_pool_of_two_workers(two_workers, tmp_path_factory):
    """Town1 run in a worker process beside Town2 gives what it gives in the study's own process. The reference is
    the mini study (Town1's first two rounds, explore, sysid, adapt and adapt_driver, in one process), which the
    reliability tests build anyway: a method's episodes do not depend on which other methods run, so the shared
    smoke study's Town1 must hold the mini study's figures for those methods and rounds, with no study run again."""
    one = mini_reference(tmp_path_factory)
    two = without_wall_time(two_workers[1])
    methods = set(mini_config().methods)
    labels = [it["label"] for it in one["iterations"]]
    assert labels == ["Offline 0", "Online 0"] and methods <= set(two["config"]["methods"])
    pooled = {it["label"]: it["towns"]["Town1"] for it in two["iterations"] if it["label"] in labels}
    for it in one["iterations"]:
        assert {m: f for m, f in pooled[it["label"]].items() if m in methods} == it["towns"]["Town1"], it["label"]
    # adapt_driver's estimates of the rounds both ran (the smoke study's Online 8 comes after)
    est_two, est_one = (r["diagnostics"]["Town1"]["adapt_driver"] for r in (two, one))
    assert est_two["prior0"] == est_one["prior0"]
    assert {k: v for k, v in est_two["estimates"].items() if k in labels} == est_one["estimates"]


def test_paper_schedule_is_the_table():
    entries = paper_schedule()
    assert [e.label for e in entries][:4] == ["Offline 0", "Offline 1", "Offline 2", "Online 0"]
    assert len([e for e in entries if e.phase == "online"]) == 15
    assert sum(e.runs_in("Town4") for e in entries if e.phase == "online") == 9
    assert entries[-1].equipment == "wheel" and entries[10].driver == "user2"


@pytest.mark.parametrize("entry, words", [
    ({"label": "a", "phase": "offline", "driver": "user1", "visual": "sunny"}, ["entry 0", "'visual'", "sunny"]),
    ({"label": "a", "phase": "later", "driver": "user1"}, ["entry 0", "'phase'"]),
    ({"label": "a", "phase": "offline", "driver": {"reaction_time": 99}}, ["entry 0", "'driver'", "reaction_time"]),
    ({"label": "a", "phase": "offline", "driver": "user1", "colour": "red"}, ["entry 0", "'colour'"]),
    ({"label": "a", "phase": "offline", "driver": "user1", "towns": ["Town9"]}, ["entry 0", "'towns'", "Town9"]),
    ({"label": "a", "phase": "offline"}, ["entry 0", "'driver'", "missing"]),
])
def test_bad_schedule_entries_name_entry_and_field(entry, words):
    with pytest.raises(ScheduleError) as err:
        parse_schedule([entry, {"label": "b", "phase": "online", "driver": "user2"}])
    for w in words:
        assert w in str(err.value)


def test_schedule_files_yaml_and_json(tmp_path):
    rows = [{"label": "warm", "phase": "offline", "driver": "user1"},
            {"label": "live", "phase": "online", "driver": {"user": "user3", "reaction_time": 2.5}, "visual": "foggy"}]
    (tmp_path / "s.json").write_text(json.dumps(rows))
    (tmp_path / "s.yaml").write_text("- {label: warm, phase: offline, driver: user1}\n"
                                     "- {label: live, phase: online, driver: {user: user3, reaction_time: 2.5}, "
                                     "visual: foggy}\n")
    a, b = load_schedule(tmp_path / "s.json"), load_schedule(tmp_path / "s.yaml")
    assert a == b and a[1].profile().reaction_time == 2.5
    with pytest.raises(ScheduleError, match="does not exist"):
        load_schedule(tmp_path / "missing.yaml")


def test_cli_bad_schedule_or_preset_exits_2_and_overwrites_nothing(tmp_path, capsys):
    out = tmp_path / "study"
    out.mkdir()
    (out / "results.json").write_text("precious")
    (out / "study.json").write_text("{}")
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps([{"label": "x", "phase": "offline", "driver": "user1", "camera": "drone"}]))
    assert main(["study", "--preset", "smoke", "--out", str(out), "--schedule", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "entry 0" in err and "'camera'" in err and len(err.strip().splitlines()) == 1
    assert main(["study", "--preset", "tiny", "--out", str(out)]) == 2
    assert "unknown preset 'tiny'" in capsys.readouterr().err
    assert main(["study", "--preset", "smoke", "--out", str(out), "--calibration", "-1"]) == 2
    assert "calibration and train.personal_updates must be >= 0" in capsys.readouterr().err
    assert main(["study", "--preset", "smoke", "--out", str(out)]) == 2  # a study is there: needs --resume
    assert "already holds a study" in capsys.readouterr().err
    assert main(["study", "--preset", "smoke", "--out", str(out), "--resume"]) == 2  # ... and it is another one
    assert "different study" in capsys.readouterr().err
    assert (out / "results.json").read_text() == "precious"
    assert sorted(p.name for p in out.iterdir()) == ["results.json", "study.json"]


def test_a_study_saved_before_an_option_existed_resumes_only_at_its_old_value(tmp_path):
    from pernav.study.study import OutputError, _fingerprint, check_output

    def saved_without(*keys: str, extra: dict | None = None) -> None:
        saved = _fingerprint(preset("smoke"))
        for key in keys:
            *parents, last = key.split(".")
            del (saved[parents[0]] if parents else saved)[last]
        (tmp_path / "study.json").write_text(json.dumps({**saved, **(extra or {})}))

    cfg = preset("smoke")
    saved_without("tau_policy", "train.road")  # as written before these options existed
    check_output(cfg, tmp_path, resume=True)  # it ran with an explore tau and no road: the same study
    for option, value, words in [("tau_policy", "retimed", "'tau_policy' differs: it predates"),
                                 ("routes", 2, "'routes' differs")]:
        changed = preset("smoke")
        setattr(changed, option, value)
        with pytest.raises(OutputError, match=words):
            check_output(changed, tmp_path, resume=True)
    changed = preset("smoke")
    changed.train.road = 4
    with pytest.raises(OutputError, match="'train.road' differs"):
        check_output(changed, tmp_path, resume=True)
    saved_without("train.backtrack")  # before it, U took the fixed step: not the default's study
    with pytest.raises(OutputError, match="'train.backtrack' is not recorded"):
        check_output(cfg, tmp_path, resume=True)
    saved_without(extra={"horizon": 5})  # an option this pernav no longer has
    with pytest.raises(OutputError, match="'horizon' is no longer an option"):
        check_output(cfg, tmp_path, resume=True)


def test_a_configuration_saved_with_the_old_name_tau_reads_as_tau_policy(tmp_path, monkeypatch):
    import pernav.study.config as config
    from pernav.study.study import OutputError, _fingerprint, check_output

    saved = {("tau" if k == "tau_policy" else k): v for k, v in _fingerprint(preset("smoke")).items()}
    (tmp_path / "study.json").write_text(json.dumps(saved))  # a study.json written before the rename
    check_output(preset("smoke"), tmp_path, resume=True)  # the same study
    changed = preset("smoke")
    changed.tau_policy = "retimed"
    with pytest.raises(OutputError, match="'tau_policy' differs"):
        check_output(changed, tmp_path, resume=True)
    (tmp_path / "smoke.yaml").write_text((config.PRESETS_DIR / "smoke.yaml").read_text())
    (tmp_path / "old.yaml").write_text("base: smoke\ntau: retimed\n")  # a preset written before the rename
    monkeypatch.setattr(config, "PRESETS_DIR", tmp_path)
    monkeypatch.setattr(config, "PRESETS", (*config.PRESETS, "old"))
    assert config.preset("old").tau_policy == "retimed"


def test_trainers_loaded_from_one_state_share_no_tensors():
    import torch
    from tensordict import TensorDict

    from pernav.model import DynamicsModel
    from pernav.trainer.buffers import RoundBuffers
    from pernav.trainer.ftml import FTMLTrainer, TrainConfig

    torch.manual_seed(0)
    buffers = RoundBuffers(L=3, seed=0)
    T = 12
    buffers.add(0, TensorDict({"observation": torch.randn(T, 14), "action": torch.randint(7, (T,)),
                               "history": torch.randn(T, 5, 21), ("next", "observation"): torch.randn(T, 14)}, [T]))
    cfg = TrainConfig(batch=4, L=3, hidden=[8])
    a = FTMLTrainer(DynamicsModel(hidden=(8,)), buffers, cfg, seed=0)
    b = FTMLTrainer(DynamicsModel(hidden=(8,)), buffers, cfg, seed=0)
    a.plain_update()
    b.load_state_dict(a.state_dict())
    moments = [s["exp_avg"].clone() for s in a.optimizer.state.values()]
    params = [p.detach().clone() for p in a.model.parameters()]
    b.plain_update()
    assert all(torch.equal(m, s["exp_avg"]) for m, s in zip(moments, a.optimizer.state.values(), strict=True))
    assert all(torch.equal(p, q) for p, q in zip(params, a.model.parameters(), strict=True))


def test_backtrack_is_a_fraction_or_null_and_the_cli_exits_2_on_a_bad_one(tmp_path, capsys):
    from pernav.study import PresetError

    cfg = preset("smoke")
    cfg.train.backtrack = 1.5
    with pytest.raises(PresetError, match=r"train.backtrack must be in \(0, 1\) or null"):
        cfg.validate()
    cfg.train.backtrack = None  # the paper's fixed step
    cfg.validate()
    assert main(["study", "--preset", "smoke", "--out", str(tmp_path / "s"), "--train-option", "backtrack=1.5"]) == 2
    assert "train.backtrack must be in (0, 1)" in capsys.readouterr().err and not (tmp_path / "s").exists()
    with pytest.raises(SystemExit) as exit_:  # the flags that repeated --train-option are gone (argparse's error)
        main(["study", "--preset", "smoke", "--out", str(tmp_path / "s"), "--adapt-step", "fixed"])
    assert exit_.value.code == 2 and "--adapt-step" in capsys.readouterr().err and not (tmp_path / "s").exists()


def test_train_options_parse_by_field_type_and_the_cli_exits_2_naming_the_bad_one(tmp_path, capsys):
    from pernav.trainer.ftml import TrainConfig

    cfg = TrainConfig().with_options(["updates=150", "lr=0.002", "backtrack=null", "hidden=[64, 64]"])
    assert (cfg.updates, cfg.lr, cfg.backtrack, cfg.hidden) == (150, 0.002, None, [64, 64])
    assert TrainConfig().updates == 50  # a copy: the defaults are untouched
    for bad, words in (("updates=1.5", "an int >= 0"), ("updates=null", "an int >= 0"), ("lr=fast", "a number"),
                       ("hidden=[0]", "positive ints"), ("depth=3", "one of the train options: lr, updates")):
        assert main(["study", "--preset", "smoke", "--out", str(tmp_path / "s"), "--train-option", bad]) == 2
        err = capsys.readouterr().err
        assert words in err and bad in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
        assert not (tmp_path / "s").exists()
    for extra, words in ((["--train-option", "personal_replay=1.5"], "train.personal_replay must be in [0, 1)"),
                         (["--train-option", "personal_replay=0.5", "--train-option", "personal_updates=0"],
                          "needs train.personal_updates > 0")):
        assert main(["study", "--preset", "smoke", "--out", str(tmp_path / "s"), *extra]) == 2
        assert words in capsys.readouterr().err
        assert not (tmp_path / "s").exists()


@pytest.mark.slow
def test_a_retimed_tau_is_re_timed_and_leaves_the_evaluation_alone(tmp_path_factory, tmp_path, capsys):
    import torch

    from pernav.study import PresetError
    from pernav.trainer.buffers import RoundBuffers

    def run(tau: str) -> tuple[dict, RoundBuffers]:
        # the mini study (Town1, the offline round and an online one): with the preset's explore tau it is the shared
        # one that tests/study/test_reliability.py compares against; re-timed, only what this test reads runs (explore's
        # evaluation, sysid's buffers): a method's episodes do not depend on which other methods run
        cfg = mini_config()
        assert cfg.towns == ["Town1"] and len(cfg.schedule) == 2 and {"explore", "sysid"} <= set(cfg.methods)
        if tau == "explore":
            assert cfg.tau_policy == "explore"
            out = mini_study(tmp_path_factory)
        else:
            cfg.tau_policy, cfg.methods, out = tau, ["explore", "sysid"], tmp_path / tau
            run_study(cfg, out)
        last = sorted((out / "checkpoints" / "Town1").glob("entry_*"))[-1]
        return json.loads((out / "results.json").read_text()), RoundBuffers.load(last / "buffers_sysid")

    explore, explore_buffers = run("explore")
    retimed, retimed_buffers = run("retimed")
    for round_ in (0, 1):  # the offline round's tau and the online round's: re-timed prompts, the same driver
        a, b = explore_buffers.tau(round_), retimed_buffers.tau(round_)
        assert not torch.equal(a["action"][: min(len(a), len(b))], b["action"][: min(len(a), len(b))])
    # no explore episode in the offline round (every drive re-timed); the online evaluation is the same episodes
    assert retimed["iterations"][0]["towns"]["Town1"] == {}
    assert explore["iterations"][0]["towns"]["Town1"]["explore"]["episodes"]
    assert retimed["iterations"][1]["towns"]["Town1"]["explore"] == explore["iterations"][1]["towns"]["Town1"]["explore"]
    cfg = preset("smoke")
    cfg.tau_policy = "random"
    with pytest.raises(PresetError, match="tau_policy must be one of explore, retimed, got 'random'"):
        cfg.validate()
    with pytest.raises(SystemExit) as exit_:  # argparse's own usage error
        main(["study", "--preset", "smoke", "--out", str(tmp_path / "s"), "--tau-policy", "random"])
    assert exit_.value.code == 2 and "--tau-policy" in capsys.readouterr().err and not (tmp_path / "s").exists()


def test_every_yaml_preset_loads_validates_and_inherits_its_base(tmp_path, monkeypatch) -> None:
    import pernav.study.config as config

    for name in config.PRESETS:
        cfg = config.preset(name)
        cfg.validate()
        assert cfg.preset == name
    personal, default = config.preset("personal"), config.preset("default")
    assert personal.train.to_dict() == default.train.to_dict() and personal.routes == 4  # base, then its own
    assert config.preset("smoke").timing["offline_drivers"] == 4 and config.preset("smoke").timing["l2"] == 3.0
    (tmp_path / "odd.yaml").write_text("towns: [Town1]\nschedule: nowhere\n")
    monkeypatch.setattr(config, "PRESETS_DIR", tmp_path)
    monkeypatch.setattr(config, "PRESETS", ("odd",))
    with pytest.raises(config.PresetError, match="schedule must be one of"):
        config.preset("odd")


def test_time_limit_factor_cuts_every_episode_and_a_bad_one_is_refused(tmp_path, capsys):
    from pernav.env.torchrl_env import explore_module
    from pernav.study.episodes import study_env
    from pernav.trainer.collect import drive
    from pernav.world.towns import get_town

    cfg = preset("smoke")
    cfg.time_limit_factor = 0.1
    limit = 0.1 * get_town("Town1").routes[0].length / 10.0 + 30.0  # the env's nominal speed: 10 m/s
    cut = drive(study_env(cfg, "Town1", cfg.schedule[0], 0, 0), explore_module())
    assert cut.shape[0] <= limit + 1 and not bool(cut[-1]["next", "completed"])
    assert bool(cut[-1]["next", "truncated"])  # cut by the time limit, not ended by arrival
    for bad in ("0", "-1", "nan"):
        out = tmp_path / f"s{bad}"
        assert main(["study", "--preset", "smoke", "--out", str(out), "--time-limit-factor", bad]) == 2
        err = capsys.readouterr().err
        assert "time_limit_factor" in err and err.count("\n") == 1 and not out.exists()
