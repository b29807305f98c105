"""Recipes that diagnose a study: they run and report what they claim."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _recipe(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "recipes" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_departure_check_replacing_a_step_by_explores_own_action_changes_nothing_and_another_does():
    from pernav.study.config import preset
    from pernav.study.runner import episode

    check = _recipe("departure_check")
    cfg = preset("default")
    entry = cfg.entries_for("Town1")[3]  # the first online round
    plain = episode(cfg, "Town1", entry, 0, 7, check.OneStepChanged(-1, 0))
    spoken = [t for t, a in enumerate(plain["action"].tolist()) if a != 0]
    t, a = spoken[0], int(plain["action"][spoken[0]])
    same = episode(cfg, "Town1", entry, 0, 7, check.OneStepChanged(t, a))
    assert same["action"].tolist() == plain["action"].tolist()
    silenced = episode(cfg, "Town1", entry, 0, 7, check.OneStepChanged(t, 0))
    assert silenced["action"][t] == 0 and plain["action"][t] != 0


@pytest.mark.parametrize("bad, message", [(["--label", "nobody"], "no round 'nobody'"),
                                          (["--action", "9"], "--action must be in 0-6")])
def test_departure_check_rejects_bad_input_with_exit_2(bad, message, tmp_path):
    args = {"--schedule": str(ROOT / "recipes/configs/headroom.yaml"), "--town": "Town1", "--label": "Online 0",
            "--route": "0", "--step": "3", "--action": "0", "--seeds": "0"}
    for k, v in zip(bad[::2], bad[1::2], strict=True):
        args[k] = v
    out = subprocess.run([sys.executable, str(ROOT / "recipes/departure_check.py"),
                          *[x for kv in args.items() for x in kv], "--json", str(tmp_path / "x.json")],
                         capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 2 and message in out.stderr and "Traceback" not in out.stderr
    assert not (tmp_path / "x.json").exists()


def test_planning_error_resume_refuses_to_mix_retime_defaults_and_leaves_the_file(tmp_path):
    from pernav.diagnostics.panel import PANEL

    driver = next(iter(PANEL))
    kept = tmp_path / "kept.json"  # one retime@true episode, written before the defaults were recorded
    kept.write_text(json.dumps({"drivers": {}, "episodes": [
        {"driver": driver, "town": "Town1", "route": 0, "seed": 1000, "method": "retime@true", "tracking_cost": 1.0}]}))
    before = kept.read_text()
    out = subprocess.run([sys.executable, str(ROOT / "recipes/planning_error.py"), "--routes", "1", "--paper-routes",
                          "0", "--drivers", driver, "--json", str(kept), "--resume"],
                         capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 2 and "would mix" in out.stderr and "Traceback" not in out.stderr
    assert kept.read_text() == before


def test_planning_error_counts_an_option_added_later_as_off_in_files_written_before_it():
    from pernav.planner.factory import PLANNER_DEFAULTS

    same = _recipe("planning_error")._same_defaults
    current = PLANNER_DEFAULTS["retime"]
    before_rescue = {k: v for k, v in current.items() if not k.startswith("rescue")}  # a file from before them
    assert current["rescue"] is None and same(before_rescue, current)
    assert not same({**before_rescue, "delay": 3}, current) and not same(None, current)
    assert not same({**current, "rescue": 10.0}, current)


def test_step_size_check_scores_each_rule_by_the_members_mean_held_out_loss(tmp_path):
    check = _recipe("step_size_check")
    # one member whose held-out loss is lowest at alpha/2 (step 0.005) and rises past alpha; on tau the loss
    # falls to alpha/2 and stalls, so Armijo (c=0.5, |g| = 20) rejects alpha and accepts alpha/2
    member = {"gnorm": 20.0, "held": [10.0, 9.8, 9.5, 9.0, 10.5, 14.0], "tau": [10.0, 9.8, 9.6, 8.9, 8.8, 9.5],
              "cv": [20.0, 19.0, 18.0, 17.0, 18.0, 25.0]}
    summary = check.summarize([{"round": 3, "members": [member, member]}])
    assert summary["fixed 0.01"] == {"lowered": 0, "rounds": 1, "mean_ratio": 1.05}
    assert summary["armijo c=0.5"] == {"lowered": 1, "rounds": 1, "mean_ratio": 0.9}
    assert summary["2-fold on tau"]["mean_ratio"] == 0.9 and summary["fixed 0.02"]["lowered"] == 0
    out = subprocess.run([sys.executable, str(ROOT / "recipes/step_size_check.py"), "--summarize", str(tmp_path)],
                         capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 2 and "no rows.json" in out.stderr and "Traceback" not in out.stderr


def test_horizon_error_refuses_a_missing_study_and_bad_users_in_one_line(tmp_path):
    for args, words in ((["--study", str(tmp_path / "none")], "no Town1 checkpoint"),
                        (["--study", str(tmp_path), "--users", "user9"], "users must be among user1")):
        out = subprocess.run([sys.executable, str(ROOT / "recipes/horizon_error.py"), *args, "--json",
                              str(tmp_path / "h.json")], capture_output=True, text=True, cwd=ROOT)
        assert out.returncode == 2 and words in out.stderr and "Traceback" not in out.stderr
        assert not (tmp_path / "h.json").exists()


def _study_results(seed: int, costs: dict[str, list[float]]) -> dict:
    """A minimal results.json: one online round in Town1 with one episode per route for each method."""
    towns = {"Town1": {m: {"episodes": [{"route": r, "tracking_cost": c} for r, c in enumerate(v)]}
                       for m, v in costs.items()}}
    return {"config": {"seed": seed}, "iterations": [{"label": "Online 0", "phase": "online", "towns": towns}]}


def test_pool_seeds_pairs_two_protocols_on_the_same_episodes(tmp_path):
    pool = _recipe("pool_seeds")
    a = [_study_results(s, {"explore": [10.0, 20.0, 30.0], "adapt": [8.0, 20.0, 25.0 + s]}) for s in (0, 1)]
    b = [_study_results(s, {"explore": [10.0, 20.0, 30.0], "adapt": [10.0, 21.0, 30.0]}) for s in (0, 1)]
    assert pool.paired_against(a, a, "adapt")["Town1"]["mean"] == 0.0
    got = pool.paired_against(a, b, "adapt")["Town1"]
    diffs = [-2.0, -1.0, -5.0, -2.0, -1.0, -4.0]  # a - b per episode, by hand
    assert got["n"] == 6 and abs(got["mean"] - sum(diffs) / 6) < 1e-12 and got["low"] <= got["mean"] <= got["high"]
    other_seed = [_study_results(5, {"explore": [10.0, 20.0, 30.0], "adapt": [1.0, 2.0, 3.0]})]
    with pytest.raises(ValueError, match="same episodes"):
        pool.paired_against(a[:1], other_seed, "adapt")
    moved = [_study_results(0, {"explore": [11.0, 20.0, 30.0], "adapt": [1.0, 2.0, 3.0]})]
    with pytest.raises(ValueError, match=r"in 1 of 3 episodes \(first: seed 0, Online 0, Town1, route 0: 10.0 vs 11.0\)"
                       r".*not paired"):
        pool.paired_against(a[:1], moved, "adapt")
    for k, r in enumerate(a + moved):  # the CLI: unpaired sets exit 2 and write nothing
        (tmp_path / f"r{k}.json").write_text(json.dumps(r))
    out = tmp_path / "pooled.json"
    run = subprocess.run([sys.executable, str(ROOT / "recipes" / "pool_seeds.py"), str(tmp_path / "r0.json"),
                          "--against", str(tmp_path / "r2.json"), "--json", str(out)], capture_output=True, text=True)
    assert run.returncode == 2 and "not paired" in run.stderr and not out.exists()


def _round(label: str, costs: dict[str, list[float]], collisions: dict[str, int] | None = None) -> dict:
    """One online Town1 round: per method, one episode per route (``collisions`` on the first episode)."""
    collisions = collisions or {}
    return {"label": label, "phase": "online", "towns": {"Town1": {
        m: {"episodes": [{"route": r, "tracking_cost": c, "collisions": collisions.get(m, 0) if r == 0 else 0}
                         for r, c in enumerate(v)]} for m, v in costs.items()}}}


def test_criterion_odds_checks_each_clause_per_subset(tmp_path):
    odds = _recipe("criterion_odds")
    head = {"explore": [100.0, 110.0, 120.0], "oracle": [50.0, 55.0, 60.0], "sysid": [95.0, 105.0, 115.0]}
    flat = {"explore": [100.0, 100.0, 100.0], "oracle": [99.0, 99.0, 99.0], "sysid": [100.0, 100.0, 100.0]}

    def study(seed: int, adapt_head: list[float], adapt_flat: list[float], crash: int = 0) -> dict:
        return {"config": {"seed": seed}, "iterations": [
            _round("Online 0", {**head, "adapt": adapt_head}, {"adapt": crash}),
            _round("Online 1", {**flat, "adapt": adapt_flat})]}

    good = study(0, [60.0, 65.0, 70.0], [100.0, 101.0, 99.0])  # closes 80 % of the gap, CI clear of zero
    above_sysid = study(1, [96.0, 106.0, 116.0], [100.0, 100.0, 100.0])  # below explore, above sysid, 8 % of gap
    crashes = study(2, [60.0, 65.0, 70.0], [100.0, 101.0, 99.0], crash=1)  # as good, one collision more
    slow_flat = study(3, [60.0, 65.0, 70.0], [115.0, 115.0, 115.0])  # 15 % above explore where no headroom
    # two rounds without headroom, 20 % above and 15 % below explore: within 10 % pooled, not round by round
    uneven = study(4, [60.0, 65.0, 70.0], [120.0, 120.0, 120.0])
    uneven["iterations"] += [_round("Online 2", {**flat, "adapt": [85.0, 85.0, 85.0]})] + [
        _round(f"Online {k}", {**head, "adapt": [60.0, 65.0, 70.0]}) for k in (3, 4)]  # the CI clear of zero
    got = odds.odds([good, above_sysid, crashes, slow_flat, uneven], "adapt", size=1)["share"]["both towns"]
    assert got["all"] == 0.4 and got["below"] == 0.8 and got["gap"] == 0.8 and got["collisions"] == 0.8
    assert got["flat"] == 0.8 and got["flat_each"] == 0.6 and got["all_strict"] == 0.2
    pooled = odds.odds([good, crashes, slow_flat], "adapt", size=3)  # one subset: the collision counts pooled
    assert pooled["subsets"] == 1 and pooled["share"]["Town1"]["collisions"] == 0.0 and pooled["share"]["Town1"]["ci"] == 1.0
    oracle = odds.odds([good, above_sysid], "oracle", size=1)["share"]["Town1"]
    assert oracle["gap"] == 1.0 and oracle["below"] == 1.0
    with pytest.raises(ValueError, match="--size must be between 1 and the number of studies"):
        odds.odds([good], "adapt", size=2)
    no_sysid = {**good, "iterations": [{**it, "towns": {"Town1": {m: v for m, v in it["towns"]["Town1"].items()
                                                                  if m != "sysid"}}} for it in good["iterations"]]}
    with pytest.raises(ValueError, match="needs adapt, oracle, sysid"):
        odds.odds([no_sysid], "adapt", size=1)
    (tmp_path / "s.json").write_text(json.dumps(good))
    run = subprocess.run([sys.executable, str(ROOT / "recipes" / "criterion_odds.py"), str(tmp_path / "s.json"),
                          "--method", "hindsight"], capture_output=True, text=True)
    assert run.returncode == 2 and "'hindsight' is not in every online round" in run.stderr
    assert "Traceback" not in run.stderr
