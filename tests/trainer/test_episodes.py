"""Episodes are what TorchRL says they are: RoundBuffers splits an add at ``("next", "done")`` (a CartPole rollout with
``break_when_any_done=False`` spanning several episodes), at a collector's ``("collector", "traj_ids")``, and a
``[B, T]`` batch into B trajectories; no sampled window crosses a reset.
"""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDictBase
from torchrl.collectors import Collector
from torchrl.envs import GymEnv, SerialEnv, TransformedEnv

from pernav.trainer import RoundBuffers
from pernav.trainer.trajectories import split_episodes
from pernav.transforms import HistoryWindow

L = 4


def _cartpole() -> TransformedEnv:
    return TransformedEnv(GymEnv("CartPole-v1"), HistoryWindow(K=1))


def _episode_lengths(done: torch.Tensor) -> list[int]:
    """The lengths of the episodes a [T] done flag marks (the last one may be cut)."""
    ends = torch.nonzero(done.reshape(-1)).flatten().tolist()
    bounds = [-1, *ends] + ([done.numel() - 1] if not ends or ends[-1] != done.numel() - 1 else [])
    return [b - a for a, b in zip(bounds[:-1], bounds[1:], strict=True)]


def _assert_no_window_crosses_a_reset(buffers: RoundBuffers, round_: int, n: int = 1000) -> None:
    """Within every sampled window, each step starts where the previous one ended (``next`` observation)."""
    windows = buffers.sample(round_, n)
    assert (windows["traj"] == windows["traj"][:, :1]).all()
    assert torch.equal(windows["next", "observation"][:, :-1], windows["observation"][:, 1:])


def test_a_rollout_spanning_several_episodes_is_split_at_done() -> None:
    env = _cartpole()
    env.set_seed(0)
    torch.manual_seed(0)
    rollout = env.rollout(300, break_when_any_done=False)  # random actions: an episode lasts ~20 steps
    lengths = _episode_lengths(rollout["next", "done"])
    assert len(lengths) > 5
    buffers = RoundBuffers(L=L, seed=0)
    buffers.add(0, rollout)
    assert buffers.lengths[0] == lengths and buffers.n_traj == len(lengths) and len(buffers) == 300
    _assert_no_window_crosses_a_reset(buffers, 0)
    # stored as one trajectory, the same data gave windows across resets
    whole = rollout.exclude(("next", "done"))
    merged = RoundBuffers(L=L, seed=0)
    merged.add(0, whole)
    windows = merged.sample(0, 1000)
    assert not torch.equal(windows["next", "observation"][:, :-1], windows["observation"][:, 1:])


def test_a_collectors_batches_are_split_by_traj_ids() -> None:
    torch.manual_seed(0)
    collector = Collector(_cartpole, policy=None, frames_per_batch=100, total_frames=200)
    buffers = RoundBuffers(L=L, seed=0)
    batches = []
    for batch in collector:
        ids = batch["collector", "traj_ids"]
        assert len(torch.unique(ids)) > 1  # several trajectories per batch
        buffers.add(len(batches), batch)
        batches.append(batch)
    collector.shutdown()
    for r, batch in enumerate(batches):
        counts = torch.unique_consecutive(batch["collector", "traj_ids"], return_counts=True)[1].tolist()
        assert buffers.lengths[r] == counts
        _assert_no_window_crosses_a_reset(buffers, r)


def test_a_batched_rollout_is_b_trajectories() -> None:
    env = SerialEnv(3, _cartpole)
    env.set_seed(0)
    torch.manual_seed(0)
    rollout = env.rollout(40, break_when_any_done=False)  # [3, 40], each row resets on its own
    assert rollout.shape == (3, 40)
    buffers = RoundBuffers(L=L, seed=0)
    buffers.add(0, rollout)
    expected = [n for row in rollout["next", "done"] for n in _episode_lengths(row)]
    assert buffers.lengths[0] == expected and len(buffers) == 120
    _assert_no_window_crosses_a_reset(buffers, 0)
    env.close()


def test_tau_is_one_episode_and_calibration_takes_each() -> None:
    env = _cartpole()
    env.set_seed(1)
    torch.manual_seed(1)
    rollout = env.rollout(200, break_when_any_done=False)
    episodes = split_episodes(rollout)
    assert len(episodes) > 1 and sum(len(e) for e in episodes) == 200
    buffers = RoundBuffers(L=L, seed=0)
    with pytest.raises(ValueError, match=rf"tau=True needs one episode, but this add holds {len(episodes)}"):
        buffers.add(0, rollout, tau=True)
    assert buffers.rounds == [] and buffers.n_traj == 0
    buffers.add(0, episodes[0], tau=True)
    buffers.add(0, rollout[len(episodes[0]):], calibration=True)
    assert len(buffers.user_trajectories(0)) == len(episodes)
    assert [len(t) for t in buffers.user_trajectories(0)] == [len(e) for e in episodes]


def test_one_episode_is_stored_as_it_is() -> None:
    env = _cartpole()
    env.set_seed(2)
    episode: TensorDictBase = env.rollout(500)  # stops at done: done only at the last step
    assert split_episodes(episode)[0] is episode
    with pytest.raises(ValueError, match=r"batch_size \(\)"):
        split_episodes(episode[0])
