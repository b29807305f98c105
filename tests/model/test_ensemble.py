"""The model ensemble: batched imagination equals member by member, training, checkpoints,
and the held-out round loss."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch
from tensordict import TensorDict

from pernav.model import DynamicsModel
from pernav.model.adapt import adapt, meta_parameters
from pernav.model.navigation import ImaginedNavigationEnv, make_world_model
from pernav.trainer.buffers import RoundBuffers
from pernav.trainer.ensemble import EnsembleTrainer
from pernav.trainer.ftml import FTMLTrainer, TrainConfig


def _trajectory(T: int, K: int = 5, seed: int = 0) -> TensorDict:
    g = torch.Generator().manual_seed(seed)
    return TensorDict({"observation": torch.randn(T, 14, generator=g), "action": torch.randint(7, (T,), generator=g),
                       "history": torch.randn(T, K, 21, generator=g),
                       ("next", "observation"): torch.randn(T, 14, generator=g)}, [T])


def test_batched_ensemble_imagination_equals_member_by_member():
    torch.manual_seed(0)
    models = [DynamicsModel(K=5, hidden=(16, 16)) for _ in range(3)]
    for i, m in enumerate(models):  # different normalization per member, so the stacked buffers matter
        g = torch.Generator().manual_seed(i)
        m.fit_normalization(torch.randn(50, 5, 21, generator=g), torch.randint(7, (50,), generator=g),
                            torch.randn(50, 14, generator=g))
    params = [meta_parameters(m).detach().clone() for m in models]
    env = ImaginedNavigationEnv(make_world_model(models[0]))
    root = TensorDict({"history": torch.randn(5, 21)}, [])
    seqs = torch.randint(7, (6, 8))
    pos, goal = env.imagine(root, seqs, params=params)
    for i, p in enumerate(params):
        p_pos, p_goal = env.imagine(root, seqs, params=[p])
        torch.testing.assert_close(pos[i], p_pos[0], rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(goal[i], p_goal[0], rtol=1e-5, atol=1e-5)
    assert not torch.allclose(pos[0], pos[1])  # the members do differ


def test_ensemble_members_differ_train_and_round_trip():
    buffers = RoundBuffers(L=3, seed=0)
    buffers.add(0, _trajectory(30), tau=True)
    buffers.add(0, _trajectory(30, seed=1))
    cfg = TrainConfig(batch=8, L=3, hidden=[16])
    ens = EnsembleTrainer(lambda: DynamicsModel(hidden=(16,)), buffers, cfg, size=3, seed=5)
    weights = [m.model.net[0].weight for m in ens.members]
    assert not torch.equal(weights[0], weights[1])
    ens.fit_normalization()
    before = [w.detach().clone() for w in weights]
    losses = ens.train(3, meta=True)
    assert len(losses) == 3 and all(torch.isfinite(torch.tensor(losses)))
    assert all(not torch.equal(b, m.model.net[0].weight) for b, m in zip(before, ens.members, strict=True))
    other = EnsembleTrainer(lambda: DynamicsModel(hidden=(16,)), buffers, cfg, size=3, seed=9)
    other.load_state_dict(ens.state_dict())
    for a, b in zip(ens.members, other.members, strict=True):
        assert all(torch.equal(x, y) for x, y in zip(a.model.state_dict().values(), b.model.state_dict().values(),
                                                     strict=True))
    params = ens.parameters(buffers.tau(0), adapted=True, alpha=0.01)
    assert len(params) == 3 and not params[0]["net", "0", "weight"].requires_grad


def test_round_loss_is_held_out_and_exact():
    from pernav.model.adapt import trajectory_windows
    from pernav.model.losses import multistep_loss

    torch.manual_seed(0)
    buffers = RoundBuffers(L=3, seed=0)
    buffers.add(0, _trajectory(12), tau=True)
    buffers.add(0, _trajectory(9, seed=1))
    trainer = EnsembleTrainer(lambda: DynamicsModel(hidden=(8,)), buffers, TrainConfig(L=3, hidden=[8]), size=1).members[0]
    held_out = buffers.data(0)[12:]  # the second trajectory
    with torch.no_grad():
        expected = float(multistep_loss(trainer.model, trajectory_windows(held_out, 3, 3)))
    assert abs(trainer.round_loss(0, adapted=False) - expected) < 1e-6
    assert trainer.round_loss(0, adapted=False) == trainer.round_loss(0, adapted=False)  # no sampling


def _two_round_ensemble(config: TrainConfig, size: int, tau_length: int, other_length: int,
                        context: int = 0, **options) -> EnsembleTrainer:
    """An ensemble of small models (seed 2, normalization fitted; ``context``: their context size) on two
    rounds of random data, each with a tau of ``tau_length`` steps and one more trajectory of ``other_length``;
    ``options``: more ``EnsembleTrainer`` arguments. The config's model fields are set to these models'."""
    config = replace(config, hidden=[16, 16], context=context)
    buffers = RoundBuffers(L=config.L, seed=0)
    for r in (0, 1):
        buffers.add(r, _trajectory(tau_length, seed=2 * r), tau=True)
        buffers.add(r, _trajectory(other_length, seed=2 * r + 1))
    ens = EnsembleTrainer(lambda: DynamicsModel(hidden=(16, 16), context=context), buffers, config, size=size,
                          seed=2, **options)
    ens.fit_normalization()
    return ens


@pytest.mark.parametrize("context", [0, 3])
def test_batched_ensemble_update_equals_each_member_stepping_alone(context):
    def make(first_order: bool) -> EnsembleTrainer:
        return _two_round_ensemble(TrainConfig(batch=12, L=3, rounds_per_update=2, first_order=first_order), 3, 20, 15,
                                   context)

    for meta, first_order in ((True, False), (True, True), (False, False)):
        batched, alone = make(first_order), make(first_order)
        batched.train(2, meta=meta)
        for _ in range(2):
            first = alone.members[0]
            batches = first.meta_batches() if meta else first.plain_batches()
            for m in alone.members:
                (m.meta_update if meta else m.plain_update)(batches)
        for a, b in zip(batched.members, alone.members, strict=True):
            for x, y in zip(a.model.parameters(), b.model.parameters(), strict=True):
                torch.testing.assert_close(x, y, rtol=1e-4, atol=1e-5)
        assert not torch.equal(batched.members[0].model.net[0].weight, make(first_order).members[0].model.net[0].weight)


@pytest.mark.slow
def test_fine_tuned_fits_the_users_drives_from_the_meta_parameters_and_leaves_the_ensemble_alone():
    from pernav.model.adapt import trajectory_windows
    from pernav.model.losses import multistep_loss

    torch.manual_seed(0)
    buffers = RoundBuffers(L=3, seed=0)
    buffers.add(0, _trajectory(30), tau=True)
    ens = EnsembleTrainer(lambda: DynamicsModel(hidden=(16,)), buffers, TrainConfig(batch=16, L=3, hidden=[16]),
                          size=2, seed=1)
    ens.fit_normalization()
    user = [_trajectory(25, seed=7), _trajectory(20, seed=8)]
    before = [meta_parameters(m.model).detach().clone() for m in ens.members]
    params = ens.fine_tuned(user, updates=60, seed=3)
    windows = torch.cat([trajectory_windows(t, 3, 3) for t in user])
    model = ens.model
    with torch.no_grad():
        for p, b in zip(params, before, strict=True):
            assert float(multistep_loss(model, windows, params=p)) < float(multistep_loss(model, windows, params=b))
            assert torch.equal(p["in_mean"], b["in_mean"])  # the meta model's normalization is kept
    for m, b in zip(ens.members, before, strict=True):  # the meta parameters are untouched
        assert all(torch.equal(x, y) for x, y in zip(meta_parameters(m.model).values(True, True),
                                                     b.values(True, True), strict=True))
    again = ens.fine_tuned(user, updates=60, seed=3)  # deterministic given the seed
    assert all(torch.equal(x, y) for x, y in zip(params[0].values(True, True), again[0].values(True, True),
                                                 strict=True))
    with pytest.raises(ValueError, match="updates >= 1"):
        ens.fine_tuned(user, updates=0)


@pytest.mark.slow
def test_replayed_personal_updates_fit_the_user_and_forget_the_population_less():
    from pernav.model.adapt import trajectory_windows
    from pernav.model.losses import multistep_loss

    torch.manual_seed(0)
    population = [_trajectory(40, seed=10 + i) for i in range(4)]
    buffers = RoundBuffers(L=3, seed=0)
    for i, t in enumerate(population):
        buffers.add(i, t, tau=True)
    ens = EnsembleTrainer(lambda: DynamicsModel(hidden=(32,)), buffers, TrainConfig(batch=32, L=3, hidden=[32]),
                          size=2, seed=1)
    ens.fit_normalization()
    ens.train(100, meta=False)  # the "meta" parameters: fitted to the population
    sampling = ens.members[0].generator.get_state(), buffers.generator.get_state()
    user = [_trajectory(30, seed=7)]
    alone = ens.fine_tuned(user, updates=100, seed=3)
    replayed = ens.fine_tuned(user, updates=100, seed=3, replay=0.5)
    assert torch.equal(ens.members[0].generator.get_state(), sampling[0])  # the study's draws are untouched
    assert torch.equal(buffers.generator.get_state(), sampling[1])
    pop = torch.cat([trajectory_windows(t, 3, 3) for t in population])
    mine = trajectory_windows(user[0], 3, 3)
    meta = [meta_parameters(m.model).detach() for m in ens.members]
    with torch.no_grad():
        for a, r, b in zip(alone, replayed, meta, strict=True):
            loss = lambda windows, p: float(multistep_loss(ens.model, windows, params=p))  # noqa: E731
            assert loss(pop, r) < loss(pop, a)  # anchored in the population's data
            assert loss(mine, r) < loss(mine, b)  # and still fitted to the user
    for bad in ({"replay": 1.0}, {"replay": -0.1}, {"replay": 0.5, "bootstrap": True}):
        with pytest.raises(ValueError, match="replay must be in"):
            ens.fine_tuned(user, updates=5, **bad)


def test_weighted_loss_is_the_weighted_mean_over_windows_and_bootstrap_members_fit_their_resample():
    from pernav.model.adapt import trajectory_windows
    from pernav.model.losses import multistep_loss

    torch.manual_seed(0)
    model = DynamicsModel(hidden=(16,))
    windows = trajectory_windows(_trajectory(30), 3, 3)
    with torch.no_grad():
        each = torch.stack([multistep_loss(model, windows[i:i + 1]) for i in range(windows.shape[0])])
        w = torch.rand(windows.shape[0])
        torch.testing.assert_close(multistep_loss(model, windows, weights=torch.ones_like(w)), each.mean())
        torch.testing.assert_close(multistep_loss(model, windows, weights=w), (each * w).sum() / w.sum())
    # bootstrap: each member fits a resample of the user's drives (by seed), so members differ from the plain fit
    buffers = RoundBuffers(L=3, seed=0)
    buffers.add(0, _trajectory(30), tau=True)
    ens = EnsembleTrainer(lambda: DynamicsModel(hidden=(16,)), buffers, TrainConfig(batch=16, L=3, hidden=[16]),
                          size=3, seed=1)
    ens.fit_normalization()
    user = [_trajectory(25, seed=s) for s in (7, 8, 9, 10)]
    plain = ens.fine_tuned(user, updates=20, seed=3)
    boot = ens.fine_tuned(user, updates=20, seed=3, bootstrap=True)
    assert boot[0]["net", "0", "weight"].shape == plain[0]["net", "0", "weight"].shape
    assert any(not torch.equal(b["net", "0", "weight"], p["net", "0", "weight"]) for b, p in zip(boot, plain, strict=True))
    again = ens.fine_tuned(user, updates=20, seed=3, bootstrap=True)
    assert all(torch.equal(a["net", "0", "weight"], b["net", "0", "weight"]) for a, b in zip(again, boot, strict=True))


def test_calibration_drives_are_user_data_held_out_of_the_round_loss_and_round_trip(tmp_path):
    buffers = RoundBuffers(L=3, seed=0)
    buffers.add(0, _trajectory(12), tau=True)
    buffers.add(0, _trajectory(10, seed=1), calibration=True)
    buffers.add(0, _trajectory(9, seed=2))  # a rollout: the only held-out data
    assert [len(t) for t in buffers.user_trajectories(0)] == [12, 10]
    trainer = EnsembleTrainer(lambda: DynamicsModel(hidden=(8,)), buffers, TrainConfig(L=3, hidden=[8]), size=1).members[0]
    from pernav.model.adapt import trajectory_windows
    from pernav.model.losses import multistep_loss

    with torch.no_grad():
        expected = float(multistep_loss(trainer.model, trajectory_windows(buffers.data(0)[22:], 3, 3)))
    assert abs(trainer.round_loss(0, adapted=False) - expected) < 1e-6
    buffers.save(tmp_path / "b")
    loaded = RoundBuffers.load(tmp_path / "b")
    assert [len(t) for t in loaded.user_trajectories(0)] == [12, 10]
    assert torch.equal(loaded.user_trajectories(0)[1]["observation"], buffers.user_trajectories(0)[1]["observation"])


def _diverging_ensemble(max_grad_norm: float | None) -> EnsembleTrainer:
    """Two members; the second's weights scaled 3x so its L-step rollouts diverge (L-step loss ~1e4, adaptation
    gradient in the thousands), as a member of a real study once did (seed 2, Town1: docs/reliability.md)."""
    ens = _two_round_ensemble(TrainConfig(batch=12, L=5, rounds_per_update=2, max_grad_norm=max_grad_norm), 2, 30, 25)
    with torch.no_grad():
        for p in ens.members[1].model.net.parameters():
            p.mul_(3.0)
    return ens


def test_clipping_keeps_a_diverging_member_learning_instead_of_frozen():
    frozen, clipped = _diverging_ensemble(None), _diverging_ensemble(100.0)
    before = [p.clone() for p in frozen.members[1].model.parameters()]
    frozen.train(5, meta=True)
    clipped.train(5, meta=True)
    # unclipped, U's step throws the adapted parameters so far that every meta loss overflows: all skipped
    assert frozen.members[1].skipped == 5 and frozen.members[0].skipped == 0
    assert all(torch.equal(a, b) for a, b in zip(before, frozen.members[1].model.parameters(), strict=True))
    # clipped, every update applies (and is counted as clipped); the healthy member is untouched by the clip
    assert clipped.skipped == 0 and clipped.members[1].clipped == 5 and clipped.members[0].clipped == 0
    assert not all(torch.equal(a, b) for a, b in zip(before, clipped.members[1].model.parameters(), strict=True))
    for a, b in zip(frozen.members[0].model.parameters(), clipped.members[0].model.parameters(), strict=True):
        assert torch.equal(a, b)


def test_adaptation_clip_bounds_the_step_per_member_and_is_exact_below_the_bound():
    ens = _diverging_ensemble(None)
    tau = ens.buffers.tau(0)
    stacked = torch.stack([meta_parameters(m.model) for m in ens.members]).detach()
    keys = [k for k, v in stacked.items(True, True) if k[0] == "net"]

    def step(max_norm):
        params = stacked.clone()
        for k in keys:  # the weights adapt; the normalization buffers do not
            params.set(k, params.get(k).requires_grad_())
        out = adapt(ens.model, tau, alpha=1.0, L=5, first_order=True, params=params, max_norm=max_norm)
        return torch.stack([sum(((out.get(k) - stacked.get(k))[i] ** 2).sum() for k in keys).sqrt() for i in (0, 1)])

    free, bounded = step(None), step(50.0)
    assert free[1] > 1000 > 50 > free[0]  # the diverging member's raw step, the healthy one's
    torch.testing.assert_close(bounded, torch.stack([free[0], torch.tensor(50.0)]))
    assert torch.equal(bounded[0], free[0])  # below the bound: bitwise unchanged


def _step_size(adapted: TensorDict, params: TensorDict, grad_step: TensorDict, keys: list) -> float:
    """The a of ``adapted = params - a * g`` given the unit step ``params - g``."""
    num = sum(((params.get(k) - adapted.get(k)) * (params.get(k) - grad_step.get(k))).sum() for k in keys)
    return float(num / sum(((params.get(k) - grad_step.get(k)) ** 2).sum() for k in keys))


def test_backtracking_takes_the_largest_halved_step_that_passes_armijo_per_member():
    from pernav.model.adapt import trajectory_windows
    from pernav.model.losses import multistep_loss

    ens = _diverging_ensemble(100.0)
    tau = ens.buffers.tau(0)
    stacked = torch.stack([meta_parameters(m.model) for m in ens.members]).detach()
    keys = [k for k, v in stacked.items(True, True) if k[0] == "net"]
    for k in keys:
        stacked.set(k, stacked.get(k).requires_grad_())
    windows = trajectory_windows(tau, 5, 5)
    for alpha in (1e-5, 0.05, 0.5, 50.0):
        got = adapt(ens.model, tau, alpha=alpha, L=5, first_order=True, params=stacked, max_norm=100.0, backtrack=0.5)
        unit = adapt(ens.model, tau, alpha=1.0, L=5, first_order=True, params=stacked, max_norm=100.0)
        with torch.no_grad():
            loss0 = multistep_loss(ens.model, windows, params=stacked)
            g2 = sum(((stacked.get(k) - unit.get(k)) ** 2).flatten(1).sum(-1) for k in keys)
            for i in range(2):
                # brute force: the first of alpha, alpha/2, alpha/4, alpha/8 whose step passes the test
                passing = [alpha / 2 ** j for j in range(4)
                           if multistep_loss(ens.model, windows, params=adapt(
                               ens.model, tau, alpha=alpha / 2 ** j, L=5, first_order=True, params=stacked,
                               max_norm=100.0))[i] <= loss0[i] - 0.5 * alpha / 2 ** j * g2[i]]
                if passing:
                    assert abs(_step_size(got[i], stacked[i], unit[i], keys) / passing[0] - 1) < 1e-2  # halvings 2x
                else:  # no step passes: U keeps the member's parameters exactly
                    assert all(torch.equal(got[i].get(k), stacked[i].get(k)) for k in keys)
                # each member's step is its own: the same as adapting that member alone
                alone = adapt(ens.members[i].model, tau, alpha=alpha, L=5, first_order=True, max_norm=100.0,
                              backtrack=0.5)
                for k in keys:
                    torch.testing.assert_close(got[i].get(k), alone.get(k), rtol=1e-3, atol=1e-3)
    tiny = adapt(ens.model, tau, alpha=1e-5, L=5, first_order=True, params=stacked, max_norm=100.0, backtrack=0.5)
    fixed = adapt(ens.model, tau, alpha=1e-5, L=5, first_order=True, params=stacked, max_norm=100.0)
    assert all(torch.equal(tiny.get(k), fixed.get(k)) for k in keys)  # a step that passes is the paper's own
    with pytest.raises(ValueError, match="backtrack"):
        adapt(ens.model, tau, alpha=0.01, L=5, first_order=False, params=stacked, backtrack=0.5)


def test_a_context_model_adapts_only_its_context_and_the_meta_update_trains_the_weights_through_it():
    ens = _two_round_ensemble(TrainConfig(batch=12, L=3, rounds_per_update=2, alpha=1.0), 2, 20, 15, context=4)
    tau = ens.buffers.tau(0)
    meta = meta_parameters(ens.model).detach().clone()
    adapted = adapt(ens.model, tau, alpha=1.0, L=3, first_order=True)
    assert not torch.equal(adapted["context"], meta["context"])
    for key, value in meta.items(True, True):
        if key != "context":
            assert torch.equal(adapted.get(key), value), key
    # batched imagination reads each member's own context
    params = ens.parameters(tau, adapted=True, alpha=1.0)
    env = ImaginedNavigationEnv(make_world_model(ens.model))
    root = TensorDict({"history": torch.randn(5, 21)}, [])
    seqs = torch.randint(7, (4, 5))
    pos, _ = env.imagine(root, seqs, params=params)
    for i, p in enumerate(params):
        torch.testing.assert_close(pos[i], env.imagine(root, seqs, params=[p])[0][0], rtol=1e-5, atol=1e-5)
    # second order: the weights also learn how the context step moves the loss (not only the loss after it)
    after = {}
    for first_order in (True, False):
        twin = _two_round_ensemble(TrainConfig(batch=12, L=3, rounds_per_update=2, alpha=1.0, first_order=first_order),
                                   2, 20, 15, context=4)
        twin.train(2, meta=True)
        after[first_order] = twin.model.net[0].weight.detach().clone()
    assert not torch.equal(after[False], meta["net", "0", "weight"])
    assert not torch.allclose(after[True], after[False], rtol=1e-4, atol=1e-6)
    assert DynamicsModel(**ens.model.config()).n_context == 4
    with pytest.raises(ValueError, match="context must be >= 0"):
        DynamicsModel(context=-1)


@pytest.mark.slow
def test_context_adaptation_learns_which_round_it_is_from_tau():
    """Two rounds whose next states differ by a constant shift only (the same windows otherwise): a context
    model meta-trained on them predicts each round better after one step on its tau than before it."""
    torch.manual_seed(0)
    buffers = RoundBuffers(L=2, seed=0)
    for r, shift in ((0, 1.5), (1, -1.5)):
        for i, tau in ((0, True), (1, False)):
            t = _trajectory(30, seed=10 * r + i)
            t["history"][..., :14] = 0.0
            t["observation"] = torch.zeros(30, 14)
            t["next", "observation"] = torch.randn(30, 14, generator=torch.Generator().manual_seed(i)) * 0.1 + shift
            buffers.add(r, t, tau=tau)
    ens = EnsembleTrainer(lambda: DynamicsModel(hidden=(32,), context=2), buffers,
                          TrainConfig(batch=32, L=2, rounds_per_update=2, alpha=1.0, lr=1e-2, backtrack=None,
                                      hidden=[32], context=2), size=1)
    ens.fit_normalization()
    ens.train(150, meta=True)
    for r in (0, 1):
        assert ens.round_loss(r, adapted=True) < 0.5 * ens.round_loss(r, adapted=False), r


@pytest.mark.parametrize("size", [1, 2])
def test_ensemble_trainer_uses_its_loss_fn_in_updates_adaptation_fine_tuning_and_round_loss(size):
    from pernav.model.losses import multistep_loss

    calls: list[str] = []

    def two_step(model, batch, params=None, **kwargs):  # the L-step loss on the first 2 steps of each window
        calls.append("stacked" if params is not None and params.batch_dims else "one")
        return multistep_loss(model, batch[:, :2], params=params, **kwargs)

    def trained(**loss) -> EnsembleTrainer:
        ens = _two_round_ensemble(TrainConfig(batch=12, L=3, rounds_per_update=2), size, 20, 15, **loss)
        ens.train(2, meta=True)
        ens.train(2, meta=False)
        return ens

    custom, default = trained(loss_fn=two_step), trained()
    assert calls.count("stacked" if size > 1 else "one") >= 4  # meta and plain updates, U inside the meta ones
    assert not torch.equal(custom.model.net[0].weight, default.model.net[0].weight)
    for step in (lambda e: e.parameters(e.buffers.tau(0), adapted=True, alpha=0.01),
                 lambda e: e.fine_tuned([_trajectory(20, seed=9)], updates=1),
                 lambda e: e.round_loss(0, adapted=False)):
        calls.clear()
        step(custom)
        assert calls, step


def test_trainers_refuse_a_config_that_disagrees_with_the_model_or_the_buffers():
    buffers = RoundBuffers(L=3, seed=0)
    buffers.add(0, _trajectory(20, K=1), tau=True)
    config = TrainConfig(K=2, hidden=[64], L=7)
    expected = (r"TrainConfig.K=2 but the model's K=1; TrainConfig.hidden=\[64\] but the model's "
                r"hidden=\[8\]; TrainConfig.L=7 but RoundBuffers.L=3 \(give each once")
    with pytest.raises(ValueError, match=expected):
        FTMLTrainer(DynamicsModel(K=1, hidden=(8,)), buffers, config)
    with pytest.raises(ValueError, match=expected):
        EnsembleTrainer(lambda: DynamicsModel(K=1, hidden=(8,)), buffers, config, size=2)
    with pytest.raises(ValueError, match=r"TrainConfig.context=1 but the model's context=2"):
        FTMLTrainer(DynamicsModel(K=1, hidden=(8,), context=2), buffers, TrainConfig(context=1))
    with pytest.raises(ValueError, match=r"TrainConfig.road=2 but the model's road=4"):
        FTMLTrainer(DynamicsModel(K=1, hidden=(8,), road=4), buffers, TrainConfig(road=2))
    trainer = FTMLTrainer(DynamicsModel(K=1, hidden=(8,)), buffers, TrainConfig(K=1, hidden=[8], L=3, batch=4))
    FTMLTrainer(DynamicsModel(K=1, hidden=(8,), road=4), buffers, TrainConfig(L=3).for_model(  # a saved model's
        DynamicsModel(K=1, hidden=(8,), road=4).config()))
    trainer.fit_normalization()
    assert len(trainer.train(1, meta=True)) == 1  # a consistent one trains


def test_each_setting_is_given_once_the_trainer_reads_the_model_and_the_buffers():
    """K, hidden, road and context left at TrainConfig's defaults are the model's, L the buffers'."""
    buffers = RoundBuffers(L=3, seed=0)
    buffers.add(0, _trajectory(20, K=1), tau=True)
    model = DynamicsModel(K=1, hidden=(8,), context=2)
    config = TrainConfig(batch=4)
    trainer = FTMLTrainer(model, buffers, config)
    assert (trainer.config.K, trainer.config.hidden, trainer.config.context, trainer.config.L) == (1, [8], 2, 3)
    assert config.K == 5 and config.L == 5  # the caller's config is not changed
    ensemble = EnsembleTrainer(lambda: DynamicsModel(K=1, hidden=(8,)), buffers, TrainConfig(batch=4), size=2)
    assert ensemble.config.L == 3 and ensemble.config.K == 1
    same = TrainConfig(batch=4, K=1, hidden=[8], L=3)
    assert FTMLTrainer(DynamicsModel(K=1, hidden=(8,)), buffers, same).config is same  # nothing to read: as given
    trainer.fit_normalization()
    assert len(trainer.train(1, meta=True)) == 1
