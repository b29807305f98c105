"""The world's timing mechanisms: per-prompt reaction times, the following car, gap acceptance."""

import math

import numpy as np

from pernav.env.policies import explore_policy, oracle_policy
from pernav.world.drivers import REACTION_CV, Context, DriverProfile, named_user, resolve
from pernav.world.simulation import World
from pernav.world.towns import get_town
from pernav.world.traffic import TrafficCar


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
    assert explore_policy().margin == 0.8  # explore's slack for the average driver
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
