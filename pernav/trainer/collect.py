"""Collecting trajectories: the navigation env with its history window, rule-based and MPC policies.

Example:
    >>> from pernav.env.torchrl_env import explore_module
    >>> env = history_env("Town1", {"route": 0, "user": "user1"}, config={"n_traffic": 2}, seed=0)
    >>> td = drive(env, explore_module(), max_steps=5)
    >>> td["history"].shape
    torch.Size([5, 5, 21])
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from typing import Any

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torchrl.envs import EnvBase, TransformedEnv

from pernav.env.layout import STATE_KEYS
from pernav.env.torchrl_env import make_torchrl_env
from pernav.model.egocentric import road_of
from pernav.transforms.history import HistoryWindow
from pernav.world.constants import Instruction

__all__ = ["derive_seed", "drive", "episode_metrics", "history_env", "in_action_space", "to_speed_actions",
           "turn_lead"]

MAX_STEPS = 2000  # the env truncates far earlier (time limit); this only bounds a runaway loop
_VELOCITY = slice(STATE_KEYS.index("vx"), STATE_KEYS.index("vy") + 1)  # the planar velocity in an observation


def derive_seed(*parts: Any) -> int:
    """A stable seed from any parts (same parts -> same seed, in any process, any order of execution)."""
    digest = hashlib.sha256(repr(parts).encode()).digest()
    return int.from_bytes(digest[:4], "little") & 0x7FFFFFFF


def history_env(town: str, options: Mapping[str, Any], config: Mapping[str, Any] | None = None,
                seed: int = 0, K: int = 5) -> EnvBase:
    """The TorchRL navigation env of ``town`` with a :class:`HistoryWindow` of length ``K``."""
    base = make_torchrl_env(town, config=dict(config or {}), options=options, seed=seed)
    n_actions = int(base.action_spec.space.n)
    return TransformedEnv(base, HistoryWindow(K=K, n_actions=n_actions))


@torch.no_grad()
def drive(env: EnvBase, policy: TensorDictModule, max_steps: int = MAX_STEPS) -> TensorDictBase:
    """One episode with ``policy``; the ``[T]`` trajectory (stops at arrival or the env's time limit)."""
    return env.rollout(max_steps, policy=policy, break_when_any_done=True)


def episode_metrics(trajectory: TensorDictBase) -> dict[str, Any]:
    """Per-episode figures from the last step's info entries."""
    last = trajectory[-1]["next"]
    return {
        "tracking_cost": round(float(last["tracking_cost"]), 4),
        "vehicle_collisions": int(last["vehicle_collisions"]),
        "edge_strikes": int(last["edge_strikes"]),
        "collisions": int(last["collisions"]),
        "missed_turns": int(last["missed_turns"]),
        "wrong_turns": int(last["wrong_turns"]),
        "extra_distance": round(float(last["extra_distance"]), 1),
        "completed": bool(last["completed"]),
        "steps": int(trajectory.shape[0]),
        "turn_lead": turn_lead(trajectory),
        # the share of steps at which the policy did not play explore's action (0 for explore itself)
        "left_explore": round(float((trajectory["action"].reshape(-1) != trajectory["explore_action"].reshape(-1))
                                    .float().mean()), 4) if "explore_action" in trajectory.keys() else None,
    }


def turn_lead(trajectory: TensorDictBase) -> float | None:
    """The mean lead (s) of a drive's "turn" prompts: the distance to the junction when each was played over the car's
    speed then (None without a played "turn", or a trajectory without the env's entries)."""
    keys = trajectory.keys(True)
    if not all(k in keys for k in ("distance_to_junction", ("next", "played"), "observation")):
        return None
    wide = "history" in keys and trajectory["history"].shape[-1] - trajectory["observation"].shape[-1] == 21
    instruction = trajectory["action"].reshape(-1) // (3 if wide else 1)  # a 21-action drive: instruction * 3 + speed
    turn = (instruction == Instruction.TURN_LEFT) | (instruction == Instruction.TURN_RIGHT)
    said = trajectory["next", "played"].reshape(-1) & turn
    if not bool(said.any()):
        return None
    speed = trajectory["observation"][:, _VELOCITY].norm(dim=-1).clamp(min=1.0)
    return round(float((trajectory["distance_to_junction"].reshape(-1) / speed)[said].mean()), 3)


def to_speed_actions(trajectory: TensorDictBase, n_instructions: int = 7) -> TensorDictBase:
    """Re-encode a 7-action trajectory in the 21-action space (normal playback: ``3 * a + 1``).

    Used to share rule-based data (which always speaks at normal speed) with a 21-action model.
    """
    out = trajectory.select("observation", "action", "history", ("next", "observation")).clone()
    road = road_of(trajectory)  # the route ahead, for a model that reads the road
    if road is not None:
        out["road"] = road.clone()
    out["action"] = out["action"] * 3 + 1
    hist = out["history"]
    S = hist.shape[-1] - n_instructions
    onehot = hist[..., S:]
    wide = hist.new_zeros(*hist.shape[:-1], 3 * n_instructions)
    wide[..., 1::3] = onehot
    out["history"] = torch.cat([hist[..., :S], wide], dim=-1)
    return out


def in_action_space(trajectory: TensorDictBase, n_actions: int) -> TensorDictBase:
    """``trajectory`` in the action space of an ``n_actions`` model: a 7-action drive (explore's, a person's)
    re-encoded for a 21-action model (:func:`to_speed_actions`); a drive already in that space as it is."""
    width = trajectory["history"].shape[-1] - trajectory["observation"].shape[-1]  # the action one-hot's
    return to_speed_actions(trajectory) if n_actions == 21 and width != 21 else trajectory
