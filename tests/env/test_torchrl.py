"""TorchRL wrapper, explore/oracle modules and the HistoryWindow transform (fast, deterministic)."""

from __future__ import annotations

import functools

import pytest
import torch
from navigation_helpers import FAST, TOWN1, S
from tensordict import TensorDictBase
from torchrl.data import Categorical, LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs import ParallelEnv, SerialEnv, TransformedEnv, check_env_specs

from pernav.env.torchrl_env import INFO_DTYPES, explore_module, make_torchrl_env, navigation_of, oracle_module
from pernav.trainer.collect import history_env
from pernav.transforms import HistoryWindow


def _env(route: int = 1, time_limit_factor: float | None = None, adaptive_speed: bool = False):
    """Module-level factory (picklable for ParallelEnv workers)."""
    config = {**FAST, "adaptive_speed": adaptive_speed}
    if time_limit_factor is not None:
        config["time_limit_factor"] = time_limit_factor
    return make_torchrl_env("Town1", config=config, options={"route": route})


def _env_with_history(K: int = 4):
    return TransformedEnv(_env(), HistoryWindow(K=K))


def _check_window(r: TensorDictBase, K: int, n_actions: int = 7) -> None:
    """Window contents along a rollout without resets (batch dims ..., time)."""
    h, nh = r["history"], r["next", "history"]
    assert h.shape == (*r.shape, K, S + n_actions) and h.dtype == torch.float32
    # newest row: current observation, no action yet
    assert torch.equal(h[..., -1, :S], r["observation"])
    assert torch.equal(nh[..., -1, :S], r["next", "observation"])
    assert not nh[..., -1, S:].any()
    # previous row of the next window: previous observation and the one-hot of the action taken
    assert torch.equal(nh[..., -2, :S], r["observation"])
    assert torch.equal(nh[..., -2, S:], torch.nn.functional.one_hot(r["action"], n_actions).float())
    # the window is shifted by one per step and carried from "next" to the root
    assert torch.equal(nh[..., :-1, :S], h[..., 1:, :S])
    assert torch.equal(nh[..., :-2, S:], h[..., 1:-1, S:])
    assert torch.equal(r["history"][..., 1:, :, :], r["next", "history"][..., :-1, :, :])


@pytest.mark.parametrize("adaptive_speed,n", [(False, 7), (True, 21)])
def test_check_env_specs(adaptive_speed: bool, n: int) -> None:
    env = make_torchrl_env(config={**FAST, "adaptive_speed": adaptive_speed}, seed=0)
    assert isinstance(env.action_spec, Categorical) and env.action_spec.space.n == n
    for key, dtype in INFO_DTYPES.items():
        assert env.observation_spec[key].dtype == dtype
    check_env_specs(env)
    check_env_specs(TransformedEnv(env, HistoryWindow(K=3, n_actions=n)))


def test_history_window_rejects_wrong_n_actions() -> None:
    env = make_torchrl_env(config={**FAST, "adaptive_speed": True})
    with pytest.raises(ValueError, match="21 actions"):
        TransformedEnv(env, HistoryWindow(n_actions=7)).observation_spec  # noqa: B018


def test_reset_options_used_at_every_reset() -> None:
    options = {"route": 4, "user": "user3", "context": {"vehicle": "cybertruck"}}
    env = make_torchrl_env(config=FAST, options=options, seed=0)
    base = navigation_of(env)
    for _ in range(2):
        env.reset()
        assert base.route_index == 4 and base.context.vehicle == "cybertruck"
        assert base.profile.reaction_time == 2.3  # user3
    env.reset(options={"route": 2})  # an explicit option overrides for that reset
    assert base.route_index == 2
    env.reset()
    assert base.route_index == 4


def test_explore_rollout_rewards_and_determinism() -> None:
    env = make_torchrl_env(config=FAST, options={"route": 1, "user": "user2"}, seed=1)
    r = env.rollout(400, policy=explore_module())
    assert torch.equal(r["action"], r["explore_action"])
    assert r["action"].dtype == torch.int64
    assert torch.allclose(r["next", "reward"].squeeze(-1), -r["next", "step_cost"])
    # the explore policy drives the route to its end (about 160 steps)
    assert bool(r["next", "completed"][-1]) and bool(r["next", "done"][-1]) and r.shape[0] < 400
    again = make_torchrl_env(config=FAST, options={"route": 1, "user": "user2"}, seed=1).rollout(
        20, policy=explore_module())
    assert torch.equal(again["next", "observation"], r["next", "observation"][:20])


def test_oracle_module() -> None:
    env = make_torchrl_env(config=FAST, seed=3)
    r = env.rollout(20, policy=oracle_module())
    assert torch.equal(r["action"], r["oracle_action"])


def test_history_window_single_env() -> None:
    env = TransformedEnv(make_torchrl_env(config=FAST, seed=0), HistoryWindow(K=5))
    td = env.reset()
    assert torch.equal(td["history"], HistoryWindow(K=5, n_actions=7).initial_window(td["observation"]))
    assert not td["history"][:, S:].any()
    r = env.rollout(30, policy=explore_module())
    _check_window(r, K=5)
    # rows before the episode start repeat s_0 with zero actions
    first = r["observation"][0]
    assert torch.equal(r["next", "history"][0, :3, :S], first.expand(3, S))
    assert not r["next", "history"][0, :3, S:].any()


def test_history_window_serial_env_with_partial_reset() -> None:
    # env 0 is truncated after 30 steps and reset alone; env 1 continues
    make = [functools.partial(_env, time_limit_factor=0.0), functools.partial(_env, time_limit_factor=1.0)]
    env = TransformedEnv(SerialEnv(2, make), HistoryWindow(K=4))
    env.set_seed(0)
    r = env.rollout(40, policy=explore_module(), break_when_any_done=False)
    assert torch.equal(r["action"], r["explore_action"])
    done = r["next", "done"].squeeze(-1)
    assert done[0].nonzero().flatten().tolist() == [29] and not done[1].any()
    _check_window(r[:, :30], K=4)
    _check_window(r[1], K=4)
    fresh = r["history"][0, 30]  # window after env 0's reset
    assert torch.equal(fresh[:, :S], r["observation"][0, 30].expand(4, S)) and not fresh[:, S:].any()
    _check_window(r[0, 30:], K=4)
    assert torch.equal(r["history"][1, 30], r["next", "history"][1, 29])
    env.close()


@pytest.mark.slow
def test_history_window_parallel_env() -> None:
    # one ParallelEnv (worker start-up dominates the cost) with a window inside its workers (it travels to
    # them as a state entry) and another one around it. Its workers are forked: spawned ones import torch and pernav
    # again (27 against 13 CPU-s for this test); torch limits a forked child to one thread, so no OpenMP pool is copied
    env = TransformedEnv(ParallelEnv(2, _env_with_history, mp_start_method="fork"), HistoryWindow(K=3, out_key="history3"))
    try:
        check_env_specs(env)
        env.set_seed(0)
        r = env.rollout(20, policy=explore_module())
    finally:
        env.close()
    assert r.shape == (2, 20)
    assert torch.equal(r["action"], r["explore_action"])
    _check_window(r, K=4)
    assert r["history3"].shape == (2, 20, 3, S + 7)
    assert torch.equal(r["history3"], r["history"][..., 1:, :])
    assert torch.equal(r["next", "history3"], r["next", "history"][..., 1:, :])
    # same seeds, same data as the serial env
    serial = SerialEnv(2, _env_with_history)
    serial.set_seed(0)
    assert torch.equal(serial.rollout(20, policy=explore_module())["next", "history"], r["next", "history"])


def test_serial_env_explore_rollout_and_replay() -> None:
    env = TransformedEnv(SerialEnv(2, _env), HistoryWindow(K=4))
    env.set_seed(0)
    r = env.rollout(25, policy=explore_module())
    _check_window(r, K=4)
    rb = TensorDictReplayBuffer(storage=LazyTensorStorage(100), batch_size=8)
    rb.extend(r.reshape(-1))
    sample = rb.sample()
    assert sample["history"].shape == (8, 4, S + 7)
    assert sample["next", "history"].shape == (8, 4, S + 7)
    assert torch.equal(sample["next", "history"][:, -2, :S], sample["observation"])
    assert HistoryWindow(K=4)(sample) is sample  # forward passes the carried window through
    env.close()


def test_history_window_one_hot_actions() -> None:
    t = HistoryWindow(K=3, n_actions=4)
    w = t.initial_window(torch.zeros(2, 5))
    nxt = torch.ones(2, 5)
    a = t.next_window(w, torch.tensor([1, 3]), nxt)
    b = t.next_window(w, torch.nn.functional.one_hot(torch.tensor([1, 3]), 4), nxt)
    c = t.next_window(w, torch.tensor([[1], [3]]), nxt)
    assert torch.equal(a, b) and torch.equal(a, c)
    assert a[:, 1, 5:].argmax(-1).tolist() == [1, 3] and not a[:, 2, 5:].any()
    with pytest.raises(ValueError):
        t.next_window(w, torch.tensor([1, 4]), nxt)


def test_real_env_specs_with_history() -> None:
    check_env_specs(history_env(*TOWN1, config=FAST, seed=0))
    check_env_specs(history_env("Town1", {"route": 1}, config={**FAST, "adaptive_speed": True}, seed=0, K=3))


def test_the_explore_table_option_declares_its_spec_and_holds_explores_prompts_ahead():
    # off by default (no key); on, the specs hold it and, where explore's plan says a prompt, the table says the plan's
    # first one too (later ones may lie past the table's 240 m)
    from torchrl.envs.utils import check_env_specs

    from pernav.env.torchrl_env import make_torchrl_env

    assert "explore_table" not in make_torchrl_env(config={"n_traffic": 2}, seed=1).observation_spec.keys()
    env = make_torchrl_env(config={"n_traffic": 2, "explore_table": True}, seed=1)
    check_env_specs(env)
    td = env.rollout(30)
    table, future = td["explore_table"], td["explore_future"]
    assert table.shape[-2:] == (10, 81)
    for t in range(td.shape[0]):
        prompts = [a for a in future[t].tolist() if a]
        if prompts:
            assert prompts[0] in table[t].unique().tolist()
        else:
            assert not bool(table[t].any())


def test_the_route_boxes_count_down_to_each_crossing_the_route_enters_and_up_from_it():
    # on by default: the metres to the next crossing's box fall as the car drives toward it; when the car's route
    # enters it, the metres since the last entry start again near zero and then grow
    from torchrl.envs.utils import check_env_specs

    from pernav.env.torchrl_env import make_torchrl_env

    env = make_torchrl_env(config={"n_traffic": 2}, seed=1)
    check_env_specs(env)
    boxes = env.rollout(60)["route_boxes"]
    ahead, entered = boxes[:, 0], boxes[:, 1]
    entries = [t for t in range(1, len(boxes)) if entered[t] < entered[t - 1]]
    assert entries, "the drive entered no crossing"
    for t in range(1, len(boxes)):
        if t not in entries:
            assert float(ahead[t]) <= float(ahead[t - 1]) + 1e-3 and float(entered[t]) >= float(entered[t - 1]) - 1e-3
        else:
            assert float(entered[t]) < 20.0
