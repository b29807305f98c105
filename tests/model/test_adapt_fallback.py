"""``U`` never makes tau worse: a backtracked ``adapt`` whose every halved step fails the sufficient-decrease test
returns the parameters unchanged and says so (Acrobot through ``GymEnv``, and a NaN tau), per member for stacked
parameters; the trainers count those fallbacks by round, through a checkpoint; ``max_norm`` has one default.
"""

from __future__ import annotations

import inspect

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs import GymEnv, TransformedEnv

from pernav.model import MAX_NORM, DynamicsModel, adapt, meta_parameters, multistep_loss, trajectory_windows
from pernav.trainer import EnsembleTrainer, FTMLTrainer, RoundBuffers, TrainConfig
from pernav.transforms import HistoryWindow

L = 3


@pytest.fixture(scope="module")
def acrobot() -> tuple[DynamicsModel, list]:
    env = TransformedEnv(GymEnv("Acrobot-v1"), HistoryWindow(K=2))  # 6-d state, 3 one-hot actions
    env.set_seed(0)
    torch.manual_seed(0)
    rollouts = [env.rollout(60) for _ in range(3)]
    model = DynamicsModel(state_dim=6, n_actions=env.action_spec, K=2, hidden=(32, 32))
    data = torch.cat(rollouts)
    model.fit_normalization(data["history"], data["action"].argmax(-1), data["next", "observation"])
    return model, rollouts


@torch.no_grad()
def _tau_loss(model: DynamicsModel, tau, params=None) -> float:
    tau = tau.clone()
    tau["action"] = tau["action"].argmax(-1) if tau["action"].ndim == 2 else tau["action"]
    return float(multistep_loss(model, trajectory_windows(tau, L, L), params=params))


def test_a_step_that_never_passes_leaves_the_parameters_unchanged(acrobot) -> None:
    model, rollouts = acrobot
    tau = rollouts[0]
    before = _tau_loss(model, tau)
    params = meta_parameters(model).detach().clone()
    # alpha / 8 of the unclipped gradient still overshoots: the old U took that step and made tau worse
    fixed = adapt(model, tau, alpha=50.0 / 8, L=L, first_order=True, max_norm=None)
    assert _tau_loss(model, tau, fixed) > before
    adapted, info = adapt(model, tau, alpha=50.0, L=L, first_order=True, max_norm=None, backtrack=0.5,
                          return_info=True)
    assert bool(info.fell_back) and info.fallbacks == 1 and float(info.step) == 0.0
    assert all(torch.equal(adapted.get(k), params.get(k)) for k in params.keys(True, True))
    assert _tau_loss(model, tau, adapted) == before


@pytest.mark.parametrize("alpha", [1e-4, 0.01, 0.3, 5.0, 200.0])
@pytest.mark.parametrize("max_norm", [None, MAX_NORM])
def test_a_backtracked_step_never_makes_tau_worse(acrobot, alpha, max_norm) -> None:
    model, rollouts = acrobot
    for tau in rollouts:
        adapted, info = adapt(model, tau, alpha=alpha, L=L, first_order=True, max_norm=max_norm, backtrack=0.5,
                              return_info=True)
        assert _tau_loss(model, tau, adapted) <= _tau_loss(model, tau)
        assert float(info.step) == 0.0 or any(float(info.step) == pytest.approx(alpha / 2 ** i) for i in range(4))


def test_a_nan_tau_keeps_the_parameters() -> None:
    torch.manual_seed(0)
    model = DynamicsModel(state_dim=2, n_actions=3, K=1, hidden=(8,))
    T = 9
    tau = TensorDict({"observation": torch.randn(T, 2), "action": torch.randint(3, (T,)),
                      "history": torch.zeros(T, 1, 5), ("next", "observation"): torch.randn(T, 2)}, [T])
    tau["next", "observation"][4, 0] = float("nan")
    adapted, info = adapt(model, tau, alpha=0.1, L=L, first_order=True, backtrack=0.5, return_info=True)
    assert bool(info.fell_back)
    assert all(torch.equal(v, model.get_parameter(".".join(k)) if isinstance(k, tuple) else model.get_parameter(k))
               for k, v in adapted.items(True, True) if k[0] == "net")


def _weights_require_grad(params: TensorDict) -> TensorDict:
    """``params`` with its weights (not the normalization buffers) requiring grad, as a module's parameters do."""
    for k in params.keys(True, True):
        if k[0] == "net":
            params.get(k).requires_grad_()
    return params


def test_stacked_members_fall_back_each_on_its_own(acrobot) -> None:
    model, rollouts = acrobot
    tau = rollouts[1]
    calm = meta_parameters(model).detach().clone()
    wild = calm.clone()
    for k in wild.keys(True, True):
        if k[0] == "net":
            wild.set(k, wild.get(k) * 30.0)  # a member whose rollouts diverge: its steps overshoot
    stacked = _weights_require_grad(torch.stack([calm, wild]))
    alpha = 0.5
    together, info = adapt(model, tau, alpha=alpha, L=L, first_order=True, params=stacked, max_norm=None,
                           backtrack=0.5, return_info=True)
    for i, member in enumerate((calm, wild)):
        alone, own = adapt(model, tau, alpha=alpha, L=L, first_order=True, params=_weights_require_grad(member.clone()),
                           max_norm=None, backtrack=0.5, return_info=True)
        assert bool(info.fell_back[i]) == bool(own.fell_back)
        for k in member.keys(True, True):
            torch.testing.assert_close(together[i].get(k), alone.get(k))
    assert info.fell_back.tolist() == [False, True]


def test_trainers_count_fallbacks_by_round_and_keep_them_in_their_state(acrobot) -> None:
    _, rollouts = acrobot
    buffers = RoundBuffers(L=L, seed=0)
    for r, t in enumerate(rollouts):
        buffers.add(r, t, tau=True)
    config = TrainConfig(batch=8, alpha=1e4, max_grad_norm=None)  # a step that always overshoots
    ensemble = EnsembleTrainer(lambda: DynamicsModel(state_dim=6, n_actions=3, K=2, hidden=(16,)), buffers, config,
                               size=2)
    ensemble.fit_normalization()
    params = ensemble.adapted_parameters(buffers.tau(2))
    assert ensemble.fallbacks == 2 and ensemble.fallback_rounds == [2]
    for member, p in zip(ensemble.members, params, strict=True):  # the planner gets the meta parameters
        assert torch.equal(p["net", "0", "weight"], member.model.net[0].weight)
    single = FTMLTrainer(ensemble.members[0].model, buffers, config)
    single.round_loss(1, adapted=True)
    assert single.fallbacks == 1 and single.fallback_rounds == [1]
    again = FTMLTrainer(DynamicsModel(state_dim=6, n_actions=3, K=2, hidden=(16,)), buffers, config)
    again.load_state_dict(single.state_dict())
    assert (again.fallbacks, again.fallback_rounds) == (1, [1])


def test_max_norm_has_one_default() -> None:
    assert inspect.signature(adapt).parameters["max_norm"].default == MAX_NORM == TrainConfig().max_grad_norm
    with pytest.raises(ValueError, match="max_norm must be > 0"):
        adapt(DynamicsModel(state_dim=2, n_actions=3, K=1, hidden=(4,)), TensorDict({}, [3]), max_norm=0.0)
    with pytest.raises(ValueError, match=r"first_order=True, backtrack=0.5"):
        adapt(DynamicsModel(state_dim=2, n_actions=3, K=1, hidden=(4,)), TensorDict({}, [3]), backtrack=0.5)
