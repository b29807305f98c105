"""Towns, routing, drivers and traffic."""

import numpy as np
import pytest
from highway_env.road.lane import CircularLane, StraightLane
from highway_env.road.road import RoadNetwork

from pernav.world.constants import TOWN_NAMES
from pernav.world.drivers import (
    PROFILE_RANGES,
    Context,
    DriverProfile,
    Population,
    ProfileError,
    named_user,
    resolve,
)
from pernav.world.routing import RouteError, astar, plan_route
from pernav.world.simulation import World
from pernav.world.towns import TownError, get_town


def test_astar_is_metric_shortest_where_bfs_is_not():
    net = RoadNetwork()
    net.add_lane("a", "d", CircularLane([0, 50], 50, -np.pi / 2, np.pi / 2))  # 1 hop, a 157 m half circle
    net.add_lane("a", "b", StraightLane([0, 0], [10, 30]))
    net.add_lane("b", "c", StraightLane([10, 30], [10, 70]))
    net.add_lane("c", "d", StraightLane([10, 70], [0, 100]))
    assert net.shortest_path("a", "d") == ["a", "d"]  # highway-env: fewest hops
    assert astar(net, "a", "d") == ["a", "b", "c", "d"]  # metres


def test_unreachable_destination_fails_fast():
    town = get_town("Town1")
    net = town.network
    with pytest.raises(RouteError, match="unreachable|not in the network"):
        astar(net, "J00:oE", "nowhere")
    island = RoadNetwork()
    island.add_lane("a", "b", StraightLane([0, 0], [10, 0]))
    island.add_lane("c", "d", StraightLane([50, 0], [60, 0]))
    with pytest.raises(RouteError, match="unreachable"):
        astar(island, "a", "d")


@pytest.mark.parametrize("name", TOWN_NAMES)
def test_towns_have_ten_valid_routes(name):
    town = get_town(name)
    assert len(town.routes) == 10
    for route in town.routes:
        kinds = [m.kind for m in route.manoeuvres if m.decision]
        assert 1000 <= route.length <= 1500
        assert sum(k in ("left", "right", "enter") for k in kinds) >= 3
        assert "left" in kinds and "right" in kinds
        if town.has_roundabout:
            assert "enter" in kinds and "exit" in kinds
        # consecutive lanes are connected (or parallel lanes of the same road: a lane change)
        for a, b in zip(route.lanes, route.lanes[1:], strict=False):
            parallel = [(b[0], b[1], k) for k in range(len(town.network.graph[b[0]][b[1]]))]
            assert any(p in town.successors[a] for p in parallel)
        # waypoints every few metres
        assert np.max(np.diff(route.s)) <= 2.0 + 1e-9


def test_towns_differ_and_cover_junction_kinds():
    towns = [get_town(n) for n in TOWN_NAMES]
    assert sum(t.has_roundabout for t in towns) >= 2
    arms = [len(j.arms) for t in towns for j in t.junctions.values() if j.kind == "cross"]
    assert 4 in arms and 3 in arms
    assert any(len(t.network.graph[a][b]) >= 2 for t in towns for a, b, _ in t.road_lanes)
    signatures = {(len(t.junctions), len(t.successors)) for t in towns}
    assert len(signatures) == len(towns)


def test_route_goal_waypoint_moves_with_speed():
    route = get_town("Town2").routes[0]
    slow = route.goal_waypoint(100.0, 2.0)
    fast = route.goal_waypoint(100.0, 12.0)
    s_slow, _ = route.project(slow)
    s_fast, _ = route.project(fast)
    assert s_fast - s_slow == pytest.approx(10.0, abs=2.1)


def test_unknown_town():
    with pytest.raises(TownError, match="unknown town 'Town9'"):
        get_town("Town9")


@pytest.mark.parametrize("field", list(PROFILE_RANGES))
def test_profile_fields_are_range_checked(field):
    lo, hi, _ = PROFILE_RANGES[field]
    with pytest.raises(ProfileError, match=field):
        DriverProfile(**{field: hi + 1.0})
    with pytest.raises(ProfileError, match=field):
        DriverProfile(**{field: lo - 1.0})
    with pytest.raises(ProfileError, match=field):
        DriverProfile(**{field: "fast"})
    DriverProfile(**{field: (lo + hi) / 2})


def test_unknown_profile_field_and_context_value():
    with pytest.raises(ProfileError, match="unknown profile field 'patience'"):
        DriverProfile.from_dict({"patience": 1.0})
    with pytest.raises(ProfileError, match="unknown vehicle 'bus'"):
        Context(vehicle="bus")
    with pytest.raises(ProfileError, match="unknown user 'user9'"):
        named_user("user9")


def test_context_modifiers_change_the_driver():
    p = named_user("user1")
    base = resolve(p, Context())
    fog = resolve(p, Context(visual="foggy"))
    truck = resolve(p, Context(vehicle="cybertruck"))
    top = resolve(p, Context(camera="top"))
    first = resolve(p, Context(camera="first_person"))
    assert fog.reaction_time > base.reaction_time and fog.sight_distance < base.sight_distance
    assert fog.speed_factor < base.speed_factor
    assert truck.vehicle.length > base.vehicle.length and truck.vehicle.max_lateral_accel < base.vehicle.max_lateral_accel
    assert top.sight_distance > base.sight_distance > first.sight_distance
    assert top.speed_misjudgement < 1.0
    assert resolve(p, Context(equipment="keyboard")).keyboard and not resolve(p, Context(equipment="wheel")).keyboard
    assert base.understanding("faster") < base.understanding("normal") < base.understanding("slower")


def test_population_samples_within_ranges():
    pop = Population(seed=3)
    for _ in range(50):
        profile, context = pop.sample()
        for name, (lo, hi, _) in PROFILE_RANGES.items():
            assert lo <= getattr(profile, name) <= hi
        assert isinstance(context, Context)
    with pytest.raises(ProfileError, match="reaction_time"):
        Population(ranges={"reaction_time": (0.1, 1.0)})


def test_named_users_are_diverse():
    users = [named_user(f"user{i}") for i in range(1, 8)]
    assert len({u.reaction_time for u in users}) >= 5
    assert min(u.reaction_time for u in users) <= 0.7 and max(u.reaction_time for u in users) >= 2.0


@pytest.mark.slow
@pytest.mark.parametrize("name", TOWN_NAMES)
def test_traffic_alone_does_not_crash(name):
    """Traffic only (the driver's car parked off the map): no traffic-traffic collision in 3 minutes."""
    town = get_town(name)
    world = World(town, resolve(named_user("user1"), Context()), town.routes[0], seed=1, n_traffic=12)
    world.ego.position = np.array([-500.0, -500.0])  # far away: traffic is spawned around it...
    world.ego.act = lambda action=None: None
    world.ego.step = lambda dt: None
    world.ego.position = town.routes[0].waypoints[0].copy()  # ...but here, at the route start, idle
    for _ in range(1800):
        world.frame()
    assert world.events.traffic_collisions == 0


def test_plan_route_passes_through_goals():
    town = get_town("Town1")
    start, goal = town.road_lanes[0], town.road_lanes[-1]
    route = plan_route(town, start, 5.0, [(goal, 20.0)])
    assert route.lanes[0] == start and route.lanes[-1][:2] == goal[:2]


def test_scalar_clamp_is_np_clip():
    """The simulator's fast scalar clamp gives np.clip's value for every kind of input, NaN and infinities included."""
    from pernav.world.scalars import clamp

    rng = np.random.default_rng(0)
    values = [*rng.normal(0, 3, 200), 0.0, -0.0, 1.0, -1.0, np.inf, -np.inf, np.nan, np.float64(2.5), 3]
    for lo, hi in [(-1, 1), (-np.pi / 4, np.pi / 4), (0.0, 1.0), (-7.0, 3.0)]:
        for x in values:
            got, want = clamp(x, lo, hi), float(np.clip(x, lo, hi))
            assert (np.isnan(got) and np.isnan(want)) or got == want, (x, lo, hi)



def test_scalar_wrap_angle_is_the_tensor_wrap():
    """The simulator's scalar angle wrap lands in [-pi, pi) and agrees with the model's tensor wrap."""
    import torch

    from pernav.model.egocentric import wrap_angle as wrap_tensor
    from pernav.world.scalars import wrap_angle

    values = [*np.random.default_rng(0).normal(0, 10, 200), 0.0, np.pi, -np.pi, 3 * np.pi, -7.5]
    wrapped = [wrap_angle(x) for x in values]
    assert all(-np.pi <= w < np.pi for w in wrapped)
    assert np.allclose(wrapped, wrap_tensor(torch.tensor(values, dtype=torch.float64)).numpy())

def test_leader_lookups_cached_per_path_equal_a_fresh_build():
    """leader_of's per-path lookups, cached on the town, equal the ones built from scratch for every path."""
    from pernav.world.simulation import _path_ahead

    town = get_town("Town3")
    lanes = list(town.routes[0].lanes)
    for start in range(len(lanes)):
        path = tuple(lanes[start:start + 4])
        cached = _path_ahead(town, path)
        assert _path_ahead(town, path) is cached  # a cache hit
        town.__dict__.pop("_path_ahead_cache")
        assert _path_ahead(town, path) == cached  # rebuilt from scratch: equal
        ahead, starts, _ = cached
        assert list(ahead) == list(path) and len(starts) == len(path) and starts[0] == 0.0
