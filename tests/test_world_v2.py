"""World v2's mechanisms (issue #31): per-prompt reaction times, the following car, gap acceptance."""

import importlib.util
import json
import math
from pathlib import Path

import numpy as np

from pernav.env.policies import explore_policy, oracle_policy
from pernav.world.drivers import REACTION_CV, Context, DriverProfile, named_user, resolve
from pernav.world.layout import audio_duration
from pernav.world.simulation import TrafficCar, World
from pernav.world.towns import get_town

ROOT = Path(__file__).resolve().parents[1]


def _world(user="user7", seed=0, n_traffic=0, context=None):
    town = get_town("Town1")
    return World(town, resolve(named_user(user), context or Context()), town.routes[0], seed=seed, n_traffic=n_traffic)


def test_reaction_draws_have_the_drivers_mean_and_spread():
    d = resolve(named_user("user3"), Context())
    z = np.random.default_rng(0).standard_normal(200_000)
    draws = np.array([d.reaction_draw(float(x)) for x in z])
    assert abs(draws.mean() - d.reaction_time) < 0.01 * d.reaction_time
    assert abs(draws.std() - REACTION_CV * d.reaction_time) < 0.05 * REACTION_CV * d.reaction_time
    assert draws.max() <= 3.0 * d.reaction_time and draws.min() > 0
    # the spread grows with the mean: a slow driver's prompts are late more often than a fast one's
    fast = resolve(named_user("user4"), Context())
    assert fast.reaction_sd < d.reaction_sd


def test_explore_timing_is_unchanged_and_the_oracle_covers_a_slow_drivers_spread():
    assert explore_policy().margin == 0.8  # 1.65 x 0.444 s < 0.8 s: world v1's slack
    slow = resolve(named_user("user3"), Context(visual="foggy"))
    assert math.isclose(oracle_policy(slow).margin, 1.65 * slow.reaction_sd)
    assert oracle_policy(slow).turn_lead(10.0) > explore_policy().turn_lead(10.0)


def test_each_played_prompt_draws_its_own_reaction():
    world = _world("user3")
    ego = world.ego
    actives = []
    for _ in range(40):
        ego.heard.clear()
        ego.hear(1, "normal", now=0.0)
        if ego.heard:
            actives.append(ego.heard[-1].active_at)
    assert len(set(np.round(actives, 6))) > 30  # not one fixed delay
    # four draws per play, always, so two policies on one seed see the same k-th draw
    a, b = _world("user3", seed=5), _world("user3", seed=5)
    a.ego.hear(1, "normal", 0.0)
    b.ego.hear(3, "normal", 0.0)
    assert a.driver_rng.random() == b.driver_rng.random()


def test_follower_sees_a_steady_car_exactly_and_a_sudden_brake_late():
    world = _world()
    car = TrafficCar(world, world.ego.path[0], 5.0, 10.0, 12.0, follow=world.ego, headway=0.8, reaction=1.5)
    dt = world.dt
    # the car ahead drives at a steady 8 m/s: the perceived gap is the true gap
    gap = 20.0
    for _ in range(30):
        car.odometer += 10.0 * dt
        gap -= (10.0 - 8.0) * dt
        seen_gap, seen_v = car.perceived(gap, 8.0, 0.0)
    assert abs(seen_gap - gap) < 1e-6 and seen_v == 8.0
    # it brakes at 8 m/s^2 from 8 m/s: for a reaction time the follower still sees it rolling
    v = 8.0
    for _ in range(10):
        car.odometer += 10.0 * dt
        v = max(v - 8.0 * dt, 0.0)
        gap -= (10.0 - v) * dt
        seen_gap, seen_v = car.perceived(gap, v, -8.0)
    assert seen_gap > gap + 3.0 and seen_v > v + 5.0


def test_a_follower_joins_behind_and_takes_the_same_lanes():
    world = _world(seed=3)
    world.FOLLOW_RATE = 1.0
    lanes_seen, ego_lanes = set(), set()
    for _step in range(60):
        for _ in range(10):
            world.frame()
            ego_lanes.update(world.ego.path)
        world.maintain_traffic()
        f = world.follower
        if f is not None:
            assert f.follow is world.ego
            rel = world.ego.position - f.position
            assert float(np.dot(rel, world.ego.direction)) > 0  # behind the navigated car
            lanes_seen.add(f.path[0])
    assert len(lanes_seen) >= 3 and lanes_seen <= ego_lanes


def test_lane_change_waits_for_a_gap():
    town = get_town("Town3")
    lane = next(k for k in town.road_lanes if len(town.network.graph[k[0]][k[1]]) == 2 and town.lane(k).length > 80)
    other = (lane[0], lane[1], 1 - lane[2])
    world = World(town, resolve(DriverProfile(), Context()), town.routes[0], seed=0, n_traffic=0)
    ego = world.ego
    ego.path, ego.s = [lane], 40.0
    assert ego.gap_free(other)
    beside = TrafficCar(world, other, 41.0, 10.0, 10.0)
    world.traffic.append(beside)
    assert not ego.gap_free(other)
    beside.s = 80.0  # well ahead
    assert ego.gap_free(other)
    beside.s, beside.speed = 30.0, 15.0  # behind and closing fast
    assert not ego.gap_free(other)


def test_calibration_recipe_pairs_explore_and_oracle(tmp_path, capsys):
    spec = importlib.util.spec_from_file_location("world_calibration", ROOT / "recipes" / "world_calibration.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out = tmp_path / "cal"
    argv = [str(out), "--towns", "Town1", "--routes", "1", "--rounds", "2", "--seeds", "0", "--workers", "1",
            "--n-traffic", "2"]
    assert mod.main(argv) == 0
    doc = json.loads((out / "calibration.json").read_text())
    eps = doc["episodes"]
    assert sorted(e["policy"] for e in eps) == ["explore", "explore", "oracle", "oracle"]
    assert {e["episode_seed"] for e in eps} == {0, 100}  # 10000 * seed + 100 * round + route, both policies
    assert set(doc["summary"]["targets"]) >= {"2_oracle_at_most_half", "3_cells_>=60%"}
    assert "| Town1 |" in (out / "calibration.md").read_text()
    assert mod.main(argv) == 2  # never overwrites a finished calibration
    assert "exists" in capsys.readouterr().err


def _premise_bound():
    spec = importlib.util.spec_from_file_location("premise_bound", ROOT / "recipes" / "premise_bound.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_late_share_matches_sampled_reaction_draws():
    """The analytic late share equals the share of simulated reaction draws that arrive too late."""
    mod = _premise_bound()
    d = resolve(named_user("user3"), Context())
    lead, before = 5.2, 3.0
    rng = np.random.default_rng(0)
    u = rng.uniform(0.0, 1.0, 200_000)  # where within the decision step the lead ran out
    r = np.array([d.reaction_draw(z) for z in rng.standard_normal(200_000)])
    sampled = float(np.mean(audio_duration(1) + r > lead + u - before))
    assert abs(mod.p_late(d, lead, before, n=401) - sampled) < 0.01
    assert mod.p_late(d, lead + 1.0, before) < mod.p_late(d, lead, before)  # earlier prompts are late less often


def test_premise_bound_lateness_and_bounds(tmp_path, capsys):
    mod = _premise_bound()
    rows = {r["round"]: r for r in mod.lateness(10.0)}
    avg = rows["Online 12"]  # user7, the average driver in the average context: the same timing
    assert avg["explore_lead_s"] == avg["oracle_lead_s"] and avg["explore_late_commit"] == avg["oracle_late_commit"]
    slow = rows["Online 8"]  # user3: explore is late, the oracle re-timed
    assert slow["explore_late_commit"] > 0.5 > 0.05 > slow["oracle_late_commit"]
    assert 0 < mod.late_cells(list(rows.values())) < 63

    def ep(policy, town, rnd, cost, coll, swerves, missed):
        label = ("Online 8", "Online 12")[rnd]  # user3 (explore late), user7 (on time)
        return {"town": town, "round": rnd, "label": label, "seed": 0, "route": 0, "policy": policy,
                "tracking_cost": cost, "collisions": coll, "swerves": swerves, "missed_turns": missed}
    eps = [ep("explore", "Town1", 0, 500.0, 0, 2, 1), ep("oracle", "Town1", 0, 400.0, 0, 0, 0),
           ep("explore", "Town1", 1, 300.0, 1, 0, 0), ep("oracle", "Town1", 1, 300.0, 1, 0, 0)]
    b = mod.bounds(eps, routes=10)
    assert b["cost_per_missed_turn"] == 100.0  # one paired miss, 100 dearer
    assert b["as measured"]["per_town"]["Town1"] == {"explore": 5.0, "oracle": 5.0}
    assert b["as measured"]["cells_oracle_10pct_cheaper"] == 1
    assert b["every swerve a collision"]["per_town"]["Town1"] == {"explore": 15.0, "oracle": 5.0}
    parts = mod.split(eps, list(rows.values()))
    assert parts["late"]["cells"] == parts["on time"]["cells"] == 1
    assert parts["late"]["tracking_diff_ci"]["mean"] == 100.0 and parts["on time"]["tracking_diff_ci"]["mean"] == 0.0

    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps({"episodes": eps}))
    assert mod.main([str(tmp_path / "pb"), "--calibration", str(cal)]) == 0
    assert "| Online 8 | user3 |" in (tmp_path / "pb" / "premise_bound.md").read_text()
    assert mod.main([str(tmp_path / "pb"), "--calibration", "none"]) == 2  # never overwrites
    assert mod.main([str(tmp_path / "pb2"), "--calibration", str(tmp_path / "missing.json")]) == 2
    assert not (tmp_path / "pb2").exists()
    assert "is not a file" in capsys.readouterr().err


def test_premise_bound_what_if_a_slower_user1_makes_more_cells_late():
    mod = _premise_bound()
    assert mod.late_cells(mod.lateness(10.0, {"user1": 1.0})) > mod.late_cells(mod.lateness(10.0)) == 24


def test_premise_bound_population_shares_are_consistent():
    mod = _premise_bound()
    pop = mod.population_lateness(20)
    assert pop["drivers"] == 20 and 0.0 <= pop["late_20pct"] <= pop["late_5pct"] <= 1.0
    assert 0.0 < pop["late_5pct"] < 1.0  # the prior holds drivers explore serves late and drivers it serves on time


def test_calibration_population_rounds_replace_the_drivers_not_the_schedule(tmp_path, capsys):
    spec = importlib.util.spec_from_file_location("world_calibration", ROOT / "recipes" / "world_calibration.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    from pernav.world.drivers import population_samples

    towns = ["Town1", "Town4"]
    paper = mod.tasks(towns, 1, [0], 8, None, average=False)
    pop = mod.tasks(towns, 1, [0], 8, None, average=False, population=True)
    # the same (town, round, route, seed) cells, so the same episode seeds; only who drives differs
    assert [(t[0], t[1], t[5], t[6]) for t in pop] == [(t[0], t[1], t[5], t[6]) for t in paper]
    assert len([t for t in pop if t[0] == "Town4"]) == 9 and len([t for t in pop if t[0] == "Town1"]) == 15
    first = population_samples(1)[0]
    assert pop[0][2] == "Population 0" and pop[0][3] == first[0].to_dict() and pop[0][4] == first[1].to_dict()
    out = tmp_path / "cal"
    assert mod.main([str(out), "--population", "--average"]) == 2 and not out.exists()
    assert "exclude each other" in capsys.readouterr().err
