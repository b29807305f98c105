"""RoundBuffers validates an add whole before it writes anything, on real CartPole rollouts (``GymEnv``'s default
one-hot actions, float32 observations): a float64 observation that float32 storage cannot hold, a NaN step, action 7
in a 2-action task, a missing key and a wrong shape are each refused by name, and the buffers then equal an untouched
twin in everything: storage, lengths, taus, the sampling generator and the next sample. What a cast keeps exactly is
cast, and non-finite values are kept only when asked.
"""

from __future__ import annotations

from collections.abc import Callable

import pytest
import torch
from tensordict import TensorDictBase
from torchrl.envs import GymEnv, TransformedEnv

from pernav.trainer import RoundBuffers
from pernav.transforms import HistoryWindow


@pytest.fixture(scope="module")
def rollouts() -> list[TensorDictBase]:
    env = TransformedEnv(GymEnv("CartPole-v1"), HistoryWindow(K=2))  # one-hot actions, float32 observations
    env.set_seed(0)
    torch.manual_seed(0)
    return [env.rollout(12, break_when_any_done=False) for _ in range(4)]


def _filled(rollouts: list[TensorDictBase]) -> RoundBuffers:
    buffers = RoundBuffers(L=3, seed=0)
    buffers.add(0, rollouts[0], tau=True)
    buffers.add(0, rollouts[1])
    buffers.add(1, rollouts[2], tau=True)
    return buffers


def _float64(t: TensorDictBase) -> TensorDictBase:
    t = t.clone()
    t["observation"] = t["observation"].double() + 1e-12  # values float32 cannot hold
    return t


def _nan_step(t: TensorDictBase) -> TensorDictBase:
    t = t.clone()
    t["next", "observation"][5, 2] = float("nan")
    return t


def _action_7(t: TensorDictBase) -> TensorDictBase:
    t = t.clone()
    t["action"] = t["action"].argmax(-1)
    t["action"][3] = 7
    return t


def _wrong_shape(t: TensorDictBase) -> TensorDictBase:
    t = t.clone()
    t["history"] = t["history"][:, :1]  # a K = 1 window into buffers holding K = 2
    return t


CAUSES: dict[str, tuple[Callable, type, str]] = {
    "a float64 observation into float32 storage": (_float64, TypeError, r"'observation' is torch.float64 but the "
                                                                        r"buffers store torch.float32"),
    "a NaN step": (_nan_step, ValueError, r"\('next', 'observation'\) at 1 step\(s\), the first step 5.*"
                                          r"allow_nonfinite=True"),
    "action 7 in a 2-action task": (_action_7, ValueError, r"action 7 is out of range for 2 actions"),
    "a missing key": (lambda t: t.exclude("history"), KeyError, r"missing \['history'\]"),
    "a wrong shape": (_wrong_shape, ValueError, r"differ from the stored data's in \['history'\]"),
}


def _assert_twins(buffers: RoundBuffers, twin: RoundBuffers) -> None:
    assert buffers.rounds == twin.rounds and buffers.lengths == twin.lengths and buffers.n_traj == twin.n_traj
    assert len(buffers) == len(twin)
    for r in twin.rounds:
        assert (buffers.data(r) == twin.data(r)).all()
    assert buffers.taus.keys() == twin.taus.keys() and all((buffers.tau(r) == twin.tau(r)).all() for r in twin.taus)
    assert torch.equal(buffers.generator.get_state(), twin.generator.get_state())
    for r in twin.rounds:  # the next draws are the twin's
        assert (buffers.sample(r, 16) == twin.sample(r, 16)).all()


@pytest.mark.parametrize("cause", sorted(CAUSES))
@pytest.mark.parametrize("round_", [0, 1, 5])  # a round with data, its tau's, and a new one
@pytest.mark.parametrize("as_tau", [False, True])
def test_a_refused_add_leaves_the_buffers_equal_to_an_untouched_twin(rollouts, cause, round_, as_tau) -> None:
    buffers, twin = _filled(rollouts), _filled(rollouts)
    make, error, message = CAUSES[cause]
    with pytest.raises(error, match=message):
        buffers.add(round_, make(rollouts[3]), tau=as_tau, calibration=as_tau)
    _assert_twins(buffers, twin)
    buffers.add(round_, rollouts[3])  # and the same data, well formed, is taken as by the twin
    twin.add(round_, rollouts[3])
    _assert_twins(buffers, twin)


def test_a_lossless_cast_is_taken_and_non_finite_values_are_kept_only_when_asked(rollouts) -> None:
    buffers, twin = _filled(rollouts), _filled(rollouts)
    exact = rollouts[3].clone()
    exact["observation"] = exact["observation"].double()  # float32 values in float64: cast back exactly
    exact["action"] = exact["action"].argmax(-1).int()  # int32 indices: stored as the int64 ones
    buffers.add(2, exact)
    twin.add(2, rollouts[3])
    _assert_twins(buffers, twin)
    assert buffers.data(2)["observation"].dtype == torch.float32
    kept = RoundBuffers(L=3, seed=0)
    kept.add(0, _nan_step(rollouts[0]), allow_nonfinite=True)
    assert torch.isnan(kept.data(0)["next", "observation"][5, 2])


def test_the_number_of_actions_comes_from_the_spec_or_the_history_window(rollouts) -> None:
    env = TransformedEnv(GymEnv("CartPole-v1"), HistoryWindow(K=2))
    declared = RoundBuffers(L=3, n_actions=env.action_spec)
    assert declared.n_actions == 2
    declared.add(0, rollouts[0])
    with pytest.raises(ValueError, match=r"out of range for 2 actions \(RoundBuffers\(n_actions=2\)\)"):
        declared.add(0, _action_7(rollouts[1]))
    with pytest.raises(ValueError, match=r"the 'history' window's action width 2"):
        RoundBuffers(L=3).add(0, _action_7(rollouts[1]))
    with pytest.raises(ValueError, match="window length"):
        RoundBuffers(L=0)
    with pytest.raises(ValueError, match="storage='disk'"):
        RoundBuffers(L=3, storage="disk")
