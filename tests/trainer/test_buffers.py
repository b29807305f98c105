"""RoundBuffers, the per-round replay of trajectories: the sampled L-step windows never cross a trajectory's end
and stay in their round, and a save then load gives the same rounds, trajectories, tau and the same next draws.
"""

from __future__ import annotations

import torch
from navigation_helpers import S
from tensordict import TensorDict

from pernav.trainer import RoundBuffers


def test_buffer_windows_stay_inside_one_trajectory() -> None:
    L = 5
    buffers = RoundBuffers(L=L, capacity=1000, seed=0)
    lengths = [7, 5, 12, 30, 6, 19]
    for marker, T in enumerate(lengths):
        obs = torch.zeros(T, S)
        obs[:, 0] = torch.arange(T, dtype=torch.float32)
        obs[:, 1] = float(marker)
        traj = TensorDict({"observation": obs, "action": torch.randint(7, (T,)), "history": torch.zeros(T, 5, 21),
                           ("next", "observation"): obs + 1}, [T])
        buffers.add(marker % 2, traj, tau=marker < 2)
    for round_ in (0, 1):
        windows = buffers.sample(round_, 400)
        assert windows.shape == (400, L)
        step, marker = windows["observation"][..., 0], windows["observation"][..., 1]
        assert (marker == marker[:, :1]).all()
        assert (windows["traj"] == windows["traj"][:, :1]).all()
        assert (step.diff(dim=1) == 1).all()
        assert (windows["round"] == round_).all()
        assert set(marker[:, 0].long().tolist()) == {m for m in range(len(lengths)) if m % 2 == round_}
        ends = torch.tensor(lengths)[marker[:, -1].long()]
        assert (step[:, -1] < ends).all()


def test_round_buffers_save_load(tmp_path) -> None:
    buffers = RoundBuffers(L=4, capacity=200, seed=3)
    g = torch.Generator().manual_seed(0)
    for i, T in enumerate([10, 8, 15]):
        buffers.add(i // 2, TensorDict({"observation": torch.randn(T, S, generator=g),
                                        "action": torch.randint(7, (T,), generator=g),
                                        "history": torch.randn(T, 5, 21, generator=g),
                                        ("next", "observation"): torch.randn(T, S, generator=g)}, [T]),
                    tau=i != 1)
    buffers.sample(0, 3)  # the generator has moved: the saved state must be the current one
    buffers.save(tmp_path / "rb")
    loaded = RoundBuffers.load(tmp_path / "rb")
    assert loaded.rounds == buffers.rounds and loaded.n_traj == buffers.n_traj and loaded.L == buffers.L
    for r in buffers.rounds:
        assert (loaded.data(r) == buffers.data(r)).all()
        assert (loaded.tau(r) == buffers.tau(r)).all()
    for r in (0, 1, 0):
        assert (loaded.sample(r, 6) == buffers.sample(r, 6)).all()


def test_what_the_navigation_sensed_survives_the_buffers_and_a_recorded_drive(tmp_path) -> None:
    from pernav.env.navigation import FRAME_KEYS
    from pernav.env.torchrl_env import explore_module
    from pernav.trainer.collect import drive, history_env
    from pernav.trainer.drives import load_drive, save_drive

    tau = drive(history_env("Town1", {"route": 0}, config={"n_traffic": 2}, seed=0), explore_module(), max_steps=25)
    step = tau["next"]  # what happened during each step, after its action
    assert step["frames"].shape == (25, 10, len(FRAME_KEYS))
    played = step["played"]
    assert played.any() and bool((step["prompt_start"][played] >= 0).all())
    assert bool((step["prompt_end"][played] > step["prompt_start"][played]).all())
    assert bool((step["prompt_start"][~played] == -1).all())
    # a prompt is said at the start of the step of the action that played it
    assert torch.equal(step["prompt_start"][played], step["time"][played] - 1.0)
    # the frames are the car's: the first column is its speed, which the step's last observation also shows
    speed = step["observation"][:, 3:5].norm(dim=-1)
    assert torch.allclose(step["frames"][:, -1, 0], speed, atol=1e-3)

    buffers = RoundBuffers(L=5)
    buffers.add(0, tau, tau=True)
    buffers.save(tmp_path / "rb")
    loaded = RoundBuffers.load(tmp_path / "rb").tau(0)
    for key in ("frames", "prompt_start", "prompt_end", "played"):
        assert torch.equal(loaded["next", key], step[key]), key
    assert ("next", "frames") not in buffers.sample(0, 2).keys(True)  # the model's windows stay lean

    path = save_drive(tau, {"steps": 25}, tmp_path, "drive")
    assert torch.equal(load_drive(path)["next", "frames"], step["frames"])
