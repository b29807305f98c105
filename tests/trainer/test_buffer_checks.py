"""RoundBuffers checks a trajectory whole before writing: every refusal leaves the storage, the trajectory ids,
``lengths``, the taus and the rounds exactly as they were; a full round refuses instead of overwriting; a one-hot
trajectory is stored as its indices; and over random sequences of adds (some refused) the lengths always describe
the storage and no sampled window crosses a trajectory's end.
"""

from __future__ import annotations

import copy

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from tensordict import TensorDict

from pernav.trainer import RoundBuffers

S, A = 3, 4  # a small state and action count: the checks do not depend on the navigation's


def trajectory(T: int, K: int = 2, marker: float = 0.0, seed: int = 0) -> TensorDict:
    """A [T] trajectory whose observation holds its step index (column 0) and a marker (column 1)."""
    g = torch.Generator().manual_seed(seed)
    obs = torch.randn(T, S, generator=g)
    obs[:, 0] = torch.arange(T, dtype=torch.float32)
    obs[:, 1] = marker
    return TensorDict({"observation": obs, "action": torch.randint(A, (T,), generator=g),
                       "history": torch.randn(T, K, S + A, generator=g), ("next", "observation"): obs + 1,
                       "reward": torch.zeros(T, 1)}, [T])


def snapshot(buffers: RoundBuffers) -> dict:
    return {"rounds": list(buffers.rounds), "n_traj": buffers.n_traj, "lengths": copy.deepcopy(buffers.lengths),
            "data": {r: buffers.data(r).clone() for r in buffers.rounds}, "taus": dict(buffers.taus),
            "calibration": {r: list(v) for r, v in buffers.calibration.items()}}


def assert_unchanged(before: dict, buffers: RoundBuffers) -> None:
    after = snapshot(buffers)
    assert after["rounds"] == before["rounds"] and after["n_traj"] == before["n_traj"]
    assert after["lengths"] == before["lengths"]
    for r, data in before["data"].items():
        now = after["data"][r]
        assert now.shape == data.shape and set(now.keys(True, True)) == set(data.keys(True, True))
        for key in data.keys(True, True):
            assert torch.equal(now.get(key), data.get(key)), key
    assert after["taus"].keys() == before["taus"].keys()
    assert all(after["taus"][r] is t for r, t in before["taus"].items())
    assert {r: [id(d) for d in v] for r, v in after["calibration"].items()} == \
        {r: [id(d) for d in v] for r, v in before["calibration"].items()}


def _malformed_one_hot() -> TensorDict:
    t = trajectory(6)
    one_hot = torch.nn.functional.one_hot(t["action"], A)
    one_hot[2] = 1  # a step with every action at once
    t["action"] = one_hot
    return t


def _set(t: TensorDict, key, value) -> TensorDict:
    t[key] = value
    return t


REFUSED = {
    "another K": (0, lambda: trajectory(10, K=3), ValueError, "history"),
    "another state size": (1, lambda: TensorDict({"observation": torch.zeros(8, S + 1), "action": torch.zeros(8),
                                                    "history": torch.zeros(8, 2, S + 1 + A),
                                                    ("next", "observation"): torch.zeros(8, S + 1)}, [8]),
                           ValueError, "observation"),
    "a missing key": (0, lambda: trajectory(8).exclude("history"), KeyError, "history"),
    "a single step": (0, lambda: trajectory(5)[0], ValueError, r"\[T\]"),
    "an empty trajectory": (0, lambda: trajectory(3)[:0], ValueError, "non-empty"),
    "a plain dict": (0, lambda: dict(trajectory(5).items()), TypeError, "TensorDict"),
    "a malformed one-hot": (0, _malformed_one_hot, ValueError, "one-hot"),
    "continuous actions": (0, lambda: _set(trajectory(6), "action", torch.rand(6)), ValueError, "whole numbers"),
    "a negative action": (0, lambda: _set(trajectory(6), "action", -torch.ones(6, dtype=torch.long)),
                          ValueError, ">= 0"),
    "a history without actions": (0, lambda: _set(trajectory(6), "history", torch.zeros(6, 2, S)), ValueError,
                                  "history"),
    "a string round id": ("1", lambda: trajectory(6), TypeError, "round_ must be an integer"),
    "a float round id": (1.0, lambda: trajectory(6), TypeError, "round_ must be an integer"),
    "a full round": (0, lambda: trajectory(31), ValueError, "capacity"),
    "a new round, refused": (7, lambda: trajectory(8, K=3), ValueError, "history"),
}


@pytest.mark.parametrize("case", sorted(REFUSED))
@pytest.mark.parametrize("as_tau", [False, True])
def test_a_refused_trajectory_changes_nothing(case: str, as_tau: bool) -> None:
    buffers = RoundBuffers(L=3, capacity=40, seed=0)
    buffers.add(0, trajectory(10, seed=1), tau=True)
    buffers.add(1, trajectory(4, seed=2), calibration=True)
    buffers.add(1, trajectory(2, seed=3))
    before = snapshot(buffers)
    round_, make, error, message = REFUSED[case]
    with pytest.raises(error, match=message):
        buffers.add(round_, make(), tau=as_tau, calibration=as_tau)
    assert_unchanged(before, buffers)
    buffers.add(0, trajectory(5, seed=4))  # and the buffers still take good data, with the next id
    assert buffers.lengths[0] == [10, 5] and buffers.n_traj == 4
    assert buffers.data(0)["traj"][-5:].tolist() == [3] * 5


def test_a_round_fills_exactly_to_its_capacity_and_refuses_more() -> None:
    buffers = RoundBuffers(L=3, capacity=20, seed=0)
    buffers.add(0, trajectory(12))
    buffers.add(0, trajectory(8))  # exactly full
    with pytest.raises(ValueError, match="capacity=20"):
        buffers.add(0, trajectory(1))
    buffers.add(1, trajectory(20))  # each round has its own capacity
    assert buffers.lengths == {0: [12, 8], 1: [20]} and len(buffers.data(0)) == 20


def test_one_hot_actions_are_stored_as_their_indices() -> None:
    for dtype in (torch.long, torch.bool, torch.float32):
        indices, one_hot = RoundBuffers(L=3, seed=0), RoundBuffers(L=3, seed=0)
        t = trajectory(9)
        indices.add(0, t, tau=True)
        one_hot.add(0, _set(t.clone(), "action", torch.nn.functional.one_hot(t["action"], A).to(dtype)), tau=True)
        assert (indices.data(0) == one_hot.data(0)).all() and (indices.tau(0) == one_hot.tau(0)).all()
        assert one_hot.data(0)["action"].dtype == torch.long
        assert (indices.sample(0, 5) == one_hot.sample(0, 5)).all()


def test_sampling_and_normalizing_need_data_and_a_number_of_windows() -> None:
    from pernav.model import DynamicsModel
    from pernav.trainer import FTMLTrainer, TrainConfig

    empty = RoundBuffers(L=3)
    with pytest.raises(ValueError, match="no data"):
        empty.all_data()
    trainer = FTMLTrainer(DynamicsModel(state_dim=S, n_actions=A, K=2, hidden=(8,)), empty,
                          TrainConfig(batch=4, L=3, K=2, hidden=[8]))
    with pytest.raises(ValueError, match="no data"):
        trainer.fit_normalization()
    buffers = RoundBuffers(L=3)
    buffers.add(0, trajectory(6))
    for bad in (0, -2, 1.5, True, "4"):
        with pytest.raises(ValueError, match="n_windows must be an integer >= 1"):
            buffers.sample(0, bad)
    with pytest.raises(TypeError, match="round_ must be an integer"):
        buffers.sample("0", 2)
    assert buffers.sample(0, 2).shape == (2, 3)


# one add: (round, length, K); K = 3 is refused (the data's K is 2), as is a length that overflows the round
adds = st.lists(st.tuples(st.integers(0, 2), st.integers(1, 14), st.sampled_from([2, 2, 2, 3])), min_size=1,
                max_size=12)


@pytest.mark.slow
@settings(max_examples=40, deadline=None, derandomize=True)
@given(adds)
def test_random_adds_keep_lengths_true_and_windows_inside_one_trajectory(sequence: list) -> None:
    L = 3
    buffers = RoundBuffers(L=L, capacity=30, seed=0)
    markers: dict[int, int] = {}  # trajectory id -> its length
    for k, (round_, T, K) in enumerate(sequence):
        before = snapshot(buffers)
        room = buffers.capacity - (len(buffers.data(round_)) if round_ in buffers.buffers else 0)
        # the first trajectory stored sets the layout (a K = 3 one first: later K = 2 ones are refused instead)
        ok = T <= room and (not buffers.buffers or buffers.data(buffers.rounds[0])["history"].shape[1] == K)
        if ok:
            markers[buffers.n_traj] = T
            buffers.add(round_, trajectory(T, K=K, marker=float(buffers.n_traj), seed=k))
        else:
            with pytest.raises(ValueError):
                buffers.add(round_, trajectory(T, K=K, marker=-1.0, seed=k))
            assert_unchanged(before, buffers)
        for r in buffers.rounds:  # lengths describe the storage, trajectory by trajectory
            ids, counts = torch.unique_consecutive(buffers.data(r)["traj"], return_counts=True)
            assert counts.tolist() == buffers.lengths[r] and [markers[int(i)] for i in ids] == buffers.lengths[r]
    for r in buffers.rounds:
        if max(buffers.lengths[r]) < L:
            continue
        windows = buffers.sample(r, 50)
        step, marker = windows["observation"][..., 0], windows["observation"][..., 1]
        assert (windows["traj"] == windows["traj"][:, :1]).all() and (marker == windows["traj"].float()).all()
        assert (step.diff(dim=1) == 1).all()
        ends = torch.tensor([markers[int(i)] for i in windows["traj"][:, 0]])
        assert (step[:, -1] < ends).all() and (windows["round"] == r).all()
