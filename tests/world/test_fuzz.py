"""Fuzzing the world (docs/reliability.md): random actions, drivers, contexts, seeds and routes.

For every town and both action spaces (7 instructions, 21 = 7 x playback speed), episodes of the
registered gymnasium env with actions drawn uniformly from the action space, a random driver from the
population prior with a random context, a random route, seed and traffic count must: raise nothing,
give only finite observations, rewards and info numbers, and end (terminated or truncated) within the
env's time limit. A hard step cap (never hit) keeps a broken time limit from hanging CI.

``PERNAV_FUZZ_EPISODES`` (default 2) sets the episodes per town and action space; e.g.
``PERNAV_FUZZ_EPISODES=50 pytest tests/world/test_fuzz.py`` for a long run. ``PERNAV_FUZZ_SEED`` shifts every
random draw (default 0; CI is deterministic).
"""

from __future__ import annotations

import math
import os

import gymnasium as gym
import numpy as np
import pytest

import pernav  # noqa: F401 - registers the gymnasium ids
from pernav.env.layout import STATE_DIM
from pernav.world.constants import TOWN_NAMES
from pernav.world.drivers import Population

EPISODES = int(os.environ.get("PERNAV_FUZZ_EPISODES", "2"))
BASE_SEED = int(os.environ.get("PERNAV_FUZZ_SEED", "0"))


def finite_numbers(info: dict) -> list[str]:
    """Keys of ``info`` whose numbers (scalars or arrays) are not all finite."""
    bad = []
    for key, value in info.items():
        if isinstance(value, (bool, np.bool_, str)):
            continue
        if isinstance(value, (int, float, np.number)):
            if not math.isfinite(float(value)):
                bad.append(key)
        elif isinstance(value, np.ndarray) and value.dtype.kind in "fiub":
            if not np.isfinite(value.astype(np.float64)).all():
                bad.append(key)
    return bad


@pytest.mark.slow
@pytest.mark.parametrize("n_actions", [7, 21])
@pytest.mark.parametrize("town", TOWN_NAMES)
def test_random_episodes_are_finite_and_end(town, n_actions):
    t = TOWN_NAMES.index(town)
    rng = np.random.default_rng([BASE_SEED, t, n_actions])
    population = Population(seed=int(rng.integers(2**31)))
    for episode in range(EPISODES):
        profile, context = population.sample()
        route, seed = int(rng.integers(10)), int(rng.integers(2**31))
        config = {"adaptive_speed": n_actions == 21, "n_traffic": int(rng.integers(0, 5))}
        env = gym.make(f"pernav/{town}-v0", config=config)
        assert env.action_space.n == n_actions
        env.action_space.seed(seed)
        where = f"{town} episode {episode}: route {route}, seed {seed}, {profile}, {context}, {config}"
        obs, info = env.reset(seed=seed, options={"route": route, "user": profile, "context": context})
        nav = env.unwrapped
        assert obs.shape == (STATE_DIM,) and np.isfinite(obs).all(), where
        assert not finite_numbers(info), (where, finite_numbers(info))
        limit = nav.time_limit
        cap = math.ceil(limit) + 5  # the env truncates at its time limit: the cap is never reached
        steps, done = 0, False
        while not done and steps < cap:
            action = env.action_space.sample()
            obs, reward, terminated, truncated, info = env.step(action)
            steps += 1
            at = f"{where}, step {steps}, action {action}"
            assert obs.shape == (STATE_DIM,) and np.isfinite(obs).all(), (at, obs)
            assert isinstance(reward, float) and math.isfinite(reward), (at, reward)
            bad = finite_numbers(info)
            assert not bad, (at, {k: info[k] for k in bad})
            assert not (terminated and truncated), at
            assert info["completed"] == terminated, at
            done = terminated or truncated
        assert done, f"{where}: not ended after {steps} steps (time limit {limit:.0f} s)"
        assert steps <= math.ceil(limit), (where, steps, limit)
        assert terminated or info["time"] >= limit, where
        env.close()
