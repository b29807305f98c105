"""NavigationEnv: gymnasium conventions, reproducibility, rendering, errors, CLI."""

import json

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import pernav  # noqa: F401  (registers the ids)
from pernav.cli import main
from pernav.env.navigation import NavigationEnv
from pernav.world.constants import TOWN_NAMES
from pernav.world.drivers import ProfileError
from pernav.world.towns import TownError


@pytest.mark.parametrize("town", TOWN_NAMES)
def test_registered(town):
    env = gym.make(f"pernav/{town}-v0")
    obs, info = env.reset(seed=0)
    assert obs.shape == (14,) and env.action_space.n == 7
    env.close()


@pytest.mark.parametrize("adaptive", [False, True])
def test_check_env(adaptive):
    env = NavigationEnv("Town2", config={"n_traffic": 3, "adaptive_speed": adaptive})
    check_env(env, skip_render_check=True)
    assert env.action_space.n == (21 if adaptive else 7)


def _trajectory(seed):
    env = NavigationEnv("Town4", config={"n_traffic": 6})
    obs, info = env.reset(seed=seed, options={"route": 2, "user": "user4"})
    out = [obs]
    for _ in range(60):
        obs, _, term, trunc, info = env.step(info["explore_action"])
        out.append(obs)
        if term or trunc:
            break
    return np.array(out)


@pytest.mark.slow
def test_seeded_runs_are_reproducible():
    a, b = _trajectory(7), _trajectory(7)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, _trajectory(8))  # traffic differs with the seed


def test_state_and_cost():
    env = NavigationEnv("Town1", config={"n_traffic": 0})
    obs, info = env.reset(seed=0, options={"route": 0})
    goal = obs[9:11]
    obs, reward, *_ = env.step(0)
    assert reward == pytest.approx(-float(np.sum((obs[:2] - goal) ** 2)), rel=1e-4)
    assert obs[2] == 0 and obs[5] == 0 and 0 <= obs[7] <= 1 and obs[12] == 0


def test_render_rgb_array():
    env = NavigationEnv("Town3", config={"n_traffic": 2}, render_mode="rgb_array")
    env.reset(seed=0)
    env.step(0)
    frame = env.render()
    assert frame.shape == (600, 600, 3) and frame.dtype == np.uint8 and frame.std() > 5


def test_bad_reset_options():
    env = NavigationEnv("Town1")
    with pytest.raises(TownError, match="route index 12 out of range"):
        env.reset(options={"route": 12})
    with pytest.raises(ProfileError, match="reaction_time"):
        env.reset(options={"user": {"reaction_time": 9}})
    with pytest.raises(ProfileError, match="unknown visual"):
        env.reset(options={"context": {"visual": "rain"}})
    with pytest.raises(ValueError, match="unknown reset option"):
        env.reset(options={"driver": "user1"})
    with pytest.raises(TownError, match="unknown town"):
        NavigationEnv("Town0")


def test_played_only_on_change_or_after_15_steps():
    env = NavigationEnv("Town1", config={"n_traffic": 0})
    env.reset(seed=0, options={"route": 0})
    played = [env.step(3)[4]["played"] for _ in range(17)]
    assert played[0] and not any(played[1:16]) and played[16]
    assert not env.step(0)[4]["played"]


@pytest.mark.parametrize(
    "argv, message",
    [
        (["drive", "--town", "Town9", "--policy", "explore", "--user", "user1"], "unknown town"),
        (["drive", "--town", "Town1", "--policy", "explore", "--user", "user1", "--routes", "10"], "out of range"),
        (["drive", "--town", "Town1", "--policy", "explore", "--user", "user42"], "unknown user"),
        (["drive", "--town", "Town1", "--policy", "explore", "--user", "missing.yaml"], "does not exist"),
        (["study", "--preset", "smoke", "--out", "runs/never", "--planner-option", "spread=1"], "max_spread"),
        (["study", "--preset", "smoke", "--out", "runs/never", "--planner-option", "agree=high"], "VALUE must be"),
        (["study", "--preset", "smoke", "--planner", "paper", "--out", "runs/never", "--planner-option",
          "max_spread=null"], "paper planner's options: horizon"),
    ],
)
def test_cli_bad_input_one_line_exit_2(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1 and "Traceback" not in err


def test_cli_profile_file_errors(tmp_path, capsys):
    bad = tmp_path / "u.yaml"
    bad.write_text("user: user1\nreaction_time: 7\n")
    assert main(["drive", "--town", "Town1", "--policy", "oracle", "--user", str(bad)]) == 2
    assert "reaction_time=7" in capsys.readouterr().err
    bad.write_text("speed: 3\n")
    assert main(["drive", "--town", "Town1", "--policy", "oracle", "--user", str(bad)]) == 2
    assert "unknown profile field 'speed'" in capsys.readouterr().err


@pytest.mark.slow
def test_cli_drive_json_and_gif(tmp_path, capsys):
    # in this process (`python -m pernav.cli` itself is run by the study and session tests): an import less
    gif = tmp_path / "r.gif"
    assert main(["drive", "--town", "Town1", "--policy", "oracle", "--user", "user2", "--routes", "4", "--traffic", "2",
                 "--json", "--gif", str(gif)]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["episodes"][0]["route"] == 4 and gif.stat().st_size > 10_000


def test_cli_towns(tmp_path):
    assert main(["towns", "--out", str(tmp_path), "--towns", "Town1", "Town4"]) == 0
    assert (tmp_path / "Town1.png").stat().st_size > 10_000 and (tmp_path / "Town4.png").exists()


def test_cli_unknown_argument_exit_2(capsys):
    # in this process (argparse's usage error is a SystemExit): the other CLI tests run `python -m pernav.cli` itself
    with pytest.raises(SystemExit) as exit_:
        main(["drive", "--town", "Town1", "--policy", "magic", "--user", "user1"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "--policy" in err and "Traceback" not in err


def _prompts_along(route, policy, speed=10.0):
    """Drive a policy along ``route`` at constant speed, playing as the env does (on change)."""
    from pernav.env.policies import NavView

    log, last, progress = [], 0, 0.0
    while progress < route.length:
        action = policy(NavView(route, progress, speed, last, log))
        if action and action != last:
            log.append((action, progress))
        last, progress = action, progress + speed
    return log


@pytest.mark.parametrize("town", TOWN_NAMES)
def test_every_turn_gets_its_own_turn_prompt(town):
    # the "turn right" said for a roundabout's exit must not count as said for a right turn after it
    from pernav.env.policies import TURN, explore_policy
    from pernav.world.towns import get_town

    for route in get_town(town).routes:
        log = _prompts_along(route, explore_policy())
        start = 0.0
        for m in (m for m in route.manoeuvres if m.decision):
            if m.kind in TURN:
                said = [s for a, s in log if a == TURN[m.kind] and start <= s < m.s]
                assert said, (town, route.name, m)
            start = m.s


def test_progress_after_reroute_follows_the_new_route():
    # Town4 route 5, seed 5: user4 misses the last right turn; the detour runs back along the same
    # road on its other side, onto which the new route's progress used to latch (then ran backwards)
    env = NavigationEnv("Town4", config={"n_traffic": 8})
    _, info = env.reset(seed=5, options={"route": 5, "user": "user4", "context": {"equipment": "keyboard"}})
    done, last, reroutes = False, 0.0, 0
    while not done:
        _, _, term, trunc, info = env.step(info["oracle_action"])
        done = term or trunc
        if info["reroutes"] != reroutes:
            reroutes, last = info["reroutes"], 0.0
            assert env.progress < 30.0, env.progress  # the new route starts where the car is
        assert env.progress >= last - 2.0, (env.time, last, env.progress)
        last = env.progress
    assert reroutes >= 1 and info["completed"]
