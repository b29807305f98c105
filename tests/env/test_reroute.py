"""Re-routing at the wrong branch: the navigation re-plans in the step the car enters a lane its route does not
continue on (issue: a navigation that follows its driver)."""

import pytest

from pernav.env.navigation import NavigationEnv


def _silent_drive(reroute: str, seed: int = 0):
    """Town1 route 0 with no prompt at all: the driver guesses at each junction and leaves the route."""
    env = NavigationEnv("Town1", config={"n_traffic": 2, "reroute": reroute})
    env.reset(seed=seed, options={"route": 0, "user": "user1"})
    original = env.route
    steps = []  # (car on a road of the route it follows, car on a road of the original route, re-routes)
    done = False
    while not done:
        _, _, term, trunc, info = env.step(0)
        done = term or trunc
        lane = env.world.ego.lane_index
        steps.append((env.on_route_road(lane), lane[:2] in original.roads, info["reroutes"]))
        if len(steps) > 400:
            break
    return steps, info


def test_the_navigation_re_plans_in_the_step_the_car_takes_a_wrong_branch():
    steps, info = _silent_drive("branch")
    assert info["reroutes"] >= 1 and info["missed_turns"] + info["wrong_turns"] >= 1
    # after every step the car is on a road of the route the navigation follows: no step is driven off it
    assert all(on for on, _, _ in steps)
    # the first re-plan comes in the very step the car first leaves the original route's roads
    first_off = next(t for t, (_, orig, _) in enumerate(steps) if not orig)
    first_reroute = next(t for t, (_, _, n) in enumerate(steps) if n >= 1)
    assert first_reroute == first_off


def test_the_rule_before_drives_off_the_route_before_it_re_plans():
    # the same drive under the distance rule: the car spends steps on a road its route does not hold
    steps, info = _silent_drive("distance")
    assert info["reroutes"] >= 1
    assert sum(not on for on, _, _ in steps) >= 1


def test_a_bad_reroute_setting_is_refused_by_name():
    with pytest.raises(ValueError, match="'reroute' must be 'branch' or 'distance'"):
        NavigationEnv("Town1", config={"reroute": "never"})
