"""The named instructions and observation entries stand for the integers the env, the prompt tables and the code
that read them by position use."""

from __future__ import annotations

import numpy as np
import pytest

from pernav.env import layout, policies
from pernav.env.navigation import NavigationEnv
from pernav.learners import timing
from pernav.model import egocentric
from pernav.play.audio import speech_file
from pernav.trainer import collect
from pernav.world.constants import (
    ACTION_NAMES,
    AUDIO_DURATION,
    N_INSTRUCTIONS,
    OPPOSITE,
    PREPARES,
    SIDE,
    SIDED,
    TURN_INSTRUCTIONS,
    TURNS,
    Instruction,
)

SPOKEN_NAMES = {Instruction.NONE: "no instruction", Instruction.TURN_LEFT: "turn left",
                Instruction.TURN_RIGHT: "turn right", Instruction.PREPARE_LEFT: "prepare to turn left",
                Instruction.PREPARE_RIGHT: "prepare to turn right", Instruction.ENTER_ROUNDABOUT: "enter the roundabout",
                Instruction.KEEP_LEFT: "keep left"}


def test_the_enum_is_the_env_action_space():
    env = NavigationEnv("Town1")
    assert [int(i) for i in Instruction] == list(range(env.action_space.n)) == list(range(N_INSTRUCTIONS))
    assert all(env.decode(i) == (i, "normal") and env.encode(i) == i for i in Instruction)
    wide = NavigationEnv("Town1", config={"adaptive_speed": True})
    assert all(wide.decode(wide.encode(i, p)) == (i, p) for i in Instruction for p in ("slower", "normal", "faster"))


def test_the_enum_names_the_spoken_prompt_tables():
    assert {i: ACTION_NAMES[i] for i in Instruction} == SPOKEN_NAMES
    assert all(speech_file(i).name == f"{int(i)}_normal.wav" for i in TURN_INSTRUCTIONS)
    assert AUDIO_DURATION[Instruction.NONE] == 0.0 and all(AUDIO_DURATION[i] > 0 for i in TURN_INSTRUCTIONS)


def test_the_groups_are_the_integers_the_code_tested():
    assert TURNS == (1, 2) and PREPARES == (3, 4) and SIDED == (1, 2, 3, 4) and TURN_INSTRUCTIONS == (1, 2, 3, 4, 5, 6)
    assert OPPOSITE == {1: 2, 2: 1, 3: 4, 4: 3} and SIDE == {1: "left", 2: "right", 3: "left", 4: "right"}
    assert all(OPPOSITE[OPPOSITE[i]] == i and SIDE[OPPOSITE[i]] != SIDE[i] for i in SIDED)
    assert all(ACTION_NAMES[i].endswith(SIDE[i]) for i in SIDED)
    assert policies.TURN == {"left": 1, "right": 2} and policies.PREPARE == {"left": 3, "right": 4}
    assert (policies.ENTER, policies.KEEP_LEFT, policies.EXIT) == (5, 6, 2) and policies.DROPPED == (1, 2, 3, 4)


def test_observation_entries_read_by_name_are_the_old_positions():
    assert layout.STATE_DIM == 14 and len(layout.STATE_KEYS) == len(set(layout.STATE_KEYS))
    assert (timing._SPEED, timing._BRAKE, timing._STEER) == ((3, 4), 13, 11)
    assert collect._VELOCITY == slice(3, 5)
    e = egocentric
    assert (e.X, e.Y, e.VX, e.VY, e.HEADING, e.GX, e.GY, e.STATE_DIM) == (0, 1, 3, 4, 6, 9, 10, 14)


@pytest.mark.parametrize("town", ["Town1"])
def test_the_named_observation_entries_hold_what_they_name(town):
    env = NavigationEnv(town, config={"n_traffic": 0})
    env.reset(seed=0, options={"route": 0})
    for _ in range(3):
        obs, *_ = env.step(0)
    ego, at = env.world.ego, {k: float(obs[i]) for i, k in enumerate(layout.STATE_KEYS)}
    assert np.allclose([at["x"], at["y"], at["vx"], at["vy"], at["heading"], at["goal_x"], at["goal_y"], at["brake"]],
                       [*ego.position, *ego.velocity, ego.heading, *env.goal, ego.brake_input], atol=1e-4)
    assert at["vx"] != 0.0
