"""Per-round replay buffers for FTML (README.md): one TorchRL ``TensorDictReplayBuffer`` per round.

Each round's buffer stores the round's transitions with ``"round"`` and ``"traj"`` metadata (a globally
unique trajectory id) and samples contiguous ``[L]`` windows with a ``SliceSampler`` keyed on ``"traj"``,
so a window never crosses the end of a trajectory (each window draws its trajectory uniformly, not by length). A
trajectory shorter than ``L`` is stored (it is still data, and may be a round's tau) but :meth:`RoundBuffers.sample`
never draws from it: it holds no whole window. ``short`` counts those per round. The round's adaptation trajectory
``tau_t`` is kept apart (:meth:`RoundBuffers.tau`), and so are the round's user's calibration drives, if any
(:meth:`RoundBuffers.user_trajectories`: tau and those). Everything saves to and loads from a folder.

An add is split into episodes as TorchRL marks them (:func:`~pernav.trainer.trajectories.split_episodes`: a
``[B, T]`` batch, a collector's ``("collector", "traj_ids")``, ``("next", "done")``) and validated whole before
anything is written (keys, shapes, dtypes cast where lossless, finite values, actions in range): a refused add
changes nothing. The storage is TorchRL's, in memory (``LazyTensorStorage``) or memory-mapped
(``LazyMemmapStorage``), on a ``device``; ``len(buffers)`` is the number of transitions stored.

Example:
    >>> import torch
    >>> from tensordict import TensorDict
    >>> buffers = RoundBuffers(L=5, seed=0)
    >>> def trajectory(T):
    ...     return TensorDict({"observation": torch.randn(T, 14), "action": torch.randint(7, (T,)),
    ...                        "history": torch.randn(T, 5, 21), ("next", "observation"): torch.randn(T, 14)}, [T])
    >>> buffers.add(0, trajectory(30), tau=True)
    >>> buffers.add(0, trajectory(20))
    >>> buffers.sample(0, 4).shape
    torch.Size([4, 5])
    >>> len(buffers.tau(0))
    30
"""

from __future__ import annotations

import copy
import json
import logging
import operator
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey
from torchrl.data import LazyMemmapStorage, LazyTensorStorage, SliceSampler, TensorDictReplayBuffer, TensorSpec
from torchrl.envs import Transform

from pernav.model.actions import action_indices
from pernav.model.dynamics import n_discrete_actions
from pernav.model.egocentric import road_of
from pernav.trainer.trajectories import cast_losslessly, check_actions, check_finite, split_episodes

__all__ = ["KEYS", "SENSING_KEYS", "STORAGES", "RoundBuffers"]

log = logging.getLogger("pernav.trainer")


@contextmanager
def _quiet_storage() -> Iterator[None]:
    """TorchRL logs ``Initialized LazyTensorStorage with ... shape`` (INFO, to stdout) when a storage is first
    filled; a round's buffer is an internal of ours, so that line stays off the user's console (TorchRL's
    warnings and errors still show)."""
    logger = logging.getLogger("torchrl")
    level = logger.level
    logger.setLevel(max(level, logging.WARNING))
    try:
        yield
    finally:
        logger.setLevel(level)

#: The entries of a transition that the model needs (everything else is dropped when stored); a trajectory with
#: the env's ``"route_ahead"`` also keeps ``"road"``, its first ``ROAD_MAX`` road points (:func:`road_of`).
KEYS = ("observation", "action", "history", ("next", "observation"))
#: What the navigation sensed between decisions (:data:`pernav.env.navigation.FRAME_KEYS`), kept with a round's tau and
#: calibration drives (under ``"next"``: step t's entries tell what happened after its action) when the trajectory
#: has it: a belief about the driver reads it at round time. The sampled
#: storage leaves it out (the dynamics model reads the decision steps only).
SENSING_KEYS = ("played", "prompt_start", "prompt_end", "frames")
#: The storages a round's buffer may use (``RoundBuffers(storage=...)``): TorchRL's, in memory or memory-mapped.
STORAGES = {"memory": LazyTensorStorage, "memmap": LazyMemmapStorage}


def _next(key: NestedKey) -> tuple[str, ...]:
    """``("next", key)`` for a key or a nested key."""
    return ("next", key) if isinstance(key, str) else ("next", *key)


def _on(data: TensorDictBase, device: torch.device) -> TensorDictBase:
    """``data`` on ``device``: itself when every entry already is there."""
    if all(value.device == device for value in data.values(True, True)):
        return data
    return data.to(device)


def _round_id(round_: int) -> int:
    """A round id as an ``int``; ``TypeError`` for anything but an integer (a str, a float, a bool)."""
    if isinstance(round_, bool):
        raise TypeError(f"round_ must be an integer round id, got the bool {round_!r}")
    try:
        return operator.index(round_)
    except TypeError:
        raise TypeError(f"round_ must be an integer round id (0, 1, ...), got {type(round_).__name__} "
                        f"{round_!r}") from None


class RoundBuffers:
    """One slice-sampling replay buffer per round, plus each round's adaptation trajectory.

    An add is checked whole before anything is written (:meth:`add`): a refused one leaves the storage, the
    trajectory ids, ``lengths``, the taus and the sampling generator as they were. A round that would exceed
    ``capacity`` refuses the trajectory (nothing is ever overwritten), so ``lengths`` always describes the storage.
    :meth:`sample` draws trajectories uniformly, not by length.

    Args:
        L: window length of :meth:`sample` (the L of the L-step loss).
        capacity: transitions per round (a trajectory that would exceed it is refused, ``ValueError``).
        seed: seed of the sampling generator (sampling is reproducible given the call sequence).
        observation_key, action_key, history_key: where a trajectory holds the state (and ``("next", key)`` the next
            one), the action and the :class:`~pernav.transforms.HistoryWindow` (its ``out_keys``); stored and
            sampled under the same names (a trainer's default loss reads them). Defaults: :data:`KEYS`.
        n_actions: the number of discrete actions (an int, or the env's ``Categorical`` / ``OneHot`` action spec);
            an action outside it is refused. ``None``: read from each trajectory's history window (its width minus
            the state's: the one-hot of the actions).
        storage: ``"memory"`` (TorchRL's ``LazyTensorStorage``) or ``"memmap"`` (``LazyMemmapStorage``, on disk).
        device: where the storage, the taus and the samples live (e.g. the model's); ``None``: the CPU.
        transform: a TorchRL ``Transform`` applied to sampled windows (each round's buffer gets its own copy), as
            ``TensorDictReplayBuffer(transform=...)``; not saved (pass it again to :meth:`load`).

    Attributes:
        lengths: each round's trajectory lengths, in the order added.
        short: each round's number of trajectories shorter than ``L``, which :meth:`sample` skips.
    """

    def __init__(self, L: int = 5, capacity: int = 10_000, seed: int = 0, *, observation_key: NestedKey = "observation",
                 action_key: NestedKey = "action", history_key: NestedKey = "history",
                 n_actions: int | TensorSpec | None = None, storage: str = "memory",
                 device: str | torch.device | None = None, transform: Transform | None = None) -> None:
        if isinstance(L, bool) or not hasattr(L, "__index__") or operator.index(L) < 1:
            raise ValueError(f"RoundBuffers(L=) is the window length of the L-step loss, an integer >= 1; got {L!r}")
        if storage not in STORAGES:
            raise ValueError(f"RoundBuffers(storage={storage!r}): choose one of {', '.join(STORAGES)} (TorchRL's "
                             "LazyTensorStorage in memory, LazyMemmapStorage on disk)")
        self.L, self.capacity = int(L), int(capacity)
        self.observation_key, self.action_key, self.history_key = observation_key, action_key, history_key
        self.n_actions = None if n_actions is None else n_discrete_actions(n_actions)
        self.storage, self.device, self.transform = storage, torch.device(device or "cpu"), transform
        self.buffers: dict[int, TensorDictReplayBuffer] = {}
        self.taus: dict[int, TensorDictBase] = {}
        self.calibration: dict[int, list[TensorDictBase]] = {}
        self.lengths: dict[int, list[int]] = {}
        self.n_traj = 0
        self.generator = torch.Generator().manual_seed(seed)

    def _new_buffer(self) -> TensorDictReplayBuffer:
        # strict_length: a trajectory shorter than L would give a short slice and break the [n, L] reshape; the
        # strict sampler leaves it out. With every trajectory at least L long both draw the same windows
        return TensorDictReplayBuffer(storage=STORAGES[self.storage](self.capacity, device=self.device),
                                      sampler=SliceSampler(slice_len=self.L, traj_key="traj", strict_length=True),
                                      transform=None if self.transform is None else copy.deepcopy(self.transform))

    def __len__(self) -> int:
        """Transitions stored, over every round (``len(buffers.buffers[r])``: one round's)."""
        return sum(len(buffer) for buffer in self.buffers.values())

    @property
    def keys(self) -> tuple[NestedKey, ...]:
        """The entries stored of each transition (:data:`KEYS` under this buffer's names)."""
        return (self.observation_key, self.action_key, self.history_key, _next(self.observation_key))

    @property
    def short(self) -> dict[int, int]:
        """Per round, the trajectories shorter than ``L`` (stored, never sampled)."""
        return {r: sum(T < self.L for T in lengths) for r, lengths in self.lengths.items()}

    @property
    def rounds(self) -> list[int]:
        """Rounds that hold data, in order."""
        return sorted(self.buffers)

    def add(self, round_: int, trajectory: TensorDictBase, tau: bool = False, calibration: bool = False, *,
            allow_nonfinite: bool = False) -> None:
        """Store the episodes of ``trajectory`` (from a ``HistoryWindow`` env) in round ``round_``'s buffer.

        ``trajectory`` is a ``[T]`` rollout or a ``[B, T]`` batch (B trajectories); it is split into episodes at a
        collector's ``("collector", "traj_ids")`` and after every ``("next", "done")`` step, each stored as its own
        trajectory (no sampled window crosses a reset). With ``tau=True`` it is also the round's adaptation
        trajectory ``tau_t`` (it must then be one episode); with ``calibration=True`` each episode is one of the
        round's user's calibration drives (:meth:`user_trajectories`). Actions may be categorical or one-hot (stored
        as indices); entries other than :attr:`keys` (and the road) are not stored.

        Everything is checked before anything is written: a refused add (``TypeError``, ``KeyError`` or
        ``ValueError``, naming the entry and the fix: missing keys, another shape or layout than the stored data's, a
        dtype the stored one cannot hold exactly, NaN or infinite values unless ``allow_nonfinite=True``, an action
        out of range, no room left) changes nothing.
        """
        round_ = _round_id(round_)
        if not isinstance(trajectory, TensorDictBase):
            raise TypeError(f"a trajectory is a [T] TensorDict (or a [B, T] batch), got {type(trajectory).__name__}")
        episodes = split_episodes(trajectory)
        if tau and len(episodes) > 1:
            raise ValueError(f"tau=True needs one episode, but this add holds {len(episodes)} (split at "
                             "('next', 'done'), ('collector', 'traj_ids') or a [B, T] batch): add the episode you "
                             "mean as tau on its own, and the others without tau")
        datas = [self._checked(episode, allow_nonfinite) for episode in episodes]
        total = sum(d.shape[0] for d in datas)
        stored = len(self.buffers[round_]) if round_ in self.buffers else 0
        if stored + total > self.capacity:
            raise ValueError(f"round {round_} holds {stored} of its capacity={self.capacity} transitions: no room for "
                             f"{total} more (RoundBuffers refuses rather than overwriting older trajectories; build it "
                             "with a larger capacity)")
        kept = []
        for k, (episode, data) in enumerate(zip(episodes, datas, strict=True)):
            T = data.shape[0]
            data.set("round", torch.full((T,), round_, dtype=torch.long, device=self.device))
            data.set("traj", torch.full((T,), self.n_traj + k, dtype=torch.long, device=self.device))
            if tau or calibration:
                kept.append(data.clone(False))
                for key in SENSING_KEYS:  # what happened during each step: the "next" entries (as the env writes them)
                    if ("next", key) in episode.keys(True):
                        kept[-1]["next", key] = episode["next", key].clone()
        # checked: from here on nothing raises on the data, and the storage, ids and lengths move together
        buffer = self.buffers[round_] if round_ in self.buffers else self._new_buffer()
        with _quiet_storage():
            buffer.extend(datas[0] if len(datas) == 1 else torch.cat(datas))
        self.buffers[round_] = buffer
        self.n_traj += len(datas)
        self.lengths.setdefault(round_, []).extend(d.shape[0] for d in datas)
        short = [d.shape[0] for d in datas if d.shape[0] < self.L]
        if short:
            log.warning("round %d: %s of %s steps shorter than L=%d; sample() skips %s (%d such in the round)", round_,
                        "a trajectory" if len(short) == 1 else f"{len(short)} trajectories", short if len(short) > 1
                        else short[0], self.L, "it" if len(short) == 1 else "them", self.short[round_])
        if tau:
            self.taus[round_] = kept[0]
        if calibration:
            self.calibration.setdefault(round_, []).extend(kept)

    def _checked(self, trajectory: TensorDictBase, allow_nonfinite: bool = False) -> TensorDictBase:
        """The entries of one episode ``trajectory`` that are stored (actions as indices, dtypes as stored, on the
        buffers' device), checked against the stored data's layout; raises for anything :meth:`add` would refuse,
        and writes nothing."""
        if trajectory.ndim != 1 or trajectory.shape[0] == 0:
            raise ValueError(f"a trajectory must be a non-empty [T] tensordict, got {tuple(trajectory.shape)}")
        present = trajectory.keys(True)
        keys = self.keys
        missing = [key for key in keys if key not in present]
        if missing:
            raise KeyError(f"a trajectory needs the entries {list(keys)}; missing {missing} (its entries: "
                           f"{sorted(present, key=str)}; RoundBuffers(observation_key=, action_key=, history_key=) "
                           "name them)")
        data = trajectory.select(*keys).clone()
        road = road_of(trajectory)  # a drive's route_ahead, or stored data's road (a user's drives for fine-tuning)
        if road is not None:
            data["road"] = road.clone()
        obs_key, next_key = self.observation_key, keys[-1]
        observation, history = data[obs_key], data[self.history_key]
        if observation.ndim != 2 or data[next_key].shape != observation.shape:
            raise ValueError(f"{obs_key!r} and {next_key!r} must both be [T, S], got "
                             f"{tuple(observation.shape)} and {tuple(data[next_key].shape)}")
        if history.ndim != 3 or history.shape[-1] <= observation.shape[-1]:
            raise ValueError(f"{self.history_key!r} must be [T, K, S + A] (a HistoryWindow's, S={observation.shape[-1]}), "
                             f"got {tuple(history.shape)}")
        width = history.shape[-1] - observation.shape[-1]
        n_actions = self.n_actions if self.n_actions is not None else width
        action = action_indices(data[self.action_key], data.shape, n_actions).long()  # one-hot: indices
        check_actions(action, n_actions, f"RoundBuffers(n_actions={n_actions})" if self.n_actions is not None
                      else f"the {self.history_key!r} window's action width {width}")
        data[self.action_key] = action
        self._check_layout(data)
        cast_losslessly(data, self._stored_dtypes())
        if not allow_nonfinite:
            check_finite(data)
        return _on(data, self.device)

    def _stored_dtypes(self) -> dict[NestedKey, torch.dtype]:
        """Each stored entry's dtype (the first add's: every round shares one layout); empty before any add."""
        if not self.buffers:
            return {}
        stored = self.data(self.rounds[0])[:1]
        return {key: stored.get(key).dtype for key in stored.keys(True, True) if key not in ("round", "traj", "index")}

    def _check_layout(self, data: TensorDictBase) -> None:
        """``ValueError`` unless ``data`` has the entries and per-step shapes of the data already stored (every
        round shares one layout: the model reads them all, :meth:`all_data`)."""
        if not self.buffers:
            return
        stored = self.data(self.rounds[0])[:1]
        expected = {key: tuple(stored.get(key).shape[1:]) for key in stored.keys(True, True)
                    if key not in ("round", "traj", "index")}  # ours and the replay buffer's own
        got = {key: tuple(data.get(key).shape[1:]) for key in data.keys(True, True)}
        if got != expected:
            differ = sorted({str(k) for k in got.keys() ^ expected.keys()}
                            | {str(k) for k in got.keys() & expected.keys() if got[k] != expected[k]})
            raise ValueError(f"the trajectory's entries differ from the stored data's in {differ}: per-step shapes "
                             f"{ {str(k): v for k, v in got.items()} } against the stored "
                             f"{ {str(k): v for k, v in expected.items()} } (e.g. another K, state size or road)")

    def tau(self, round_: int) -> TensorDictBase:
        """The adaptation trajectory of a round."""
        if round_ not in self.taus:
            raise KeyError(f"round {round_} has no adaptation trajectory; rounds with one: {sorted(self.taus)}")
        return self.taus[round_]

    def user_trajectories(self, round_: int) -> list[TensorDictBase]:
        """What a round's user drove before the round's evaluation: ``tau_t``, then the calibration drives."""
        return [self.tau(round_), *self.calibration.get(round_, [])]

    @classmethod
    def of(cls, trajectories: list[TensorDictBase], L: int = 5, seed: int = 0, per_round: int = 8) -> RoundBuffers:
        """Buffers holding ``trajectories`` (``per_round`` to a round: a round's storage is allocated whole),
        the first one as round 0's tau: the data of a model trained on these trajectories alone."""
        out = cls(L=L, seed=seed)
        for k, t in enumerate(trajectories):
            out.add(k // per_round, t, tau=(k == 0))
        return out

    def data(self, round_: int) -> TensorDictBase:
        """All transitions of a round, ``[N]``."""
        buffer = self.buffers[round_]
        return buffer.storage[: len(buffer)]

    def sample(self, round_: int, n_windows: int) -> TensorDictBase:
        """``[n_windows, L]`` contiguous windows of round ``round_`` (never across a trajectory end, never from a
        trajectory shorter than ``L``); ``ValueError`` if the round has no trajectory of ``L`` steps or more.

        Each window draws a trajectory uniformly among the round's of ``L`` steps or more (TorchRL's
        ``SliceSampler``), not in proportion to its length, then its start uniformly within it: a short
        trajectory's steps are drawn more often than a long one's."""
        round_ = _round_id(round_)
        if isinstance(n_windows, bool) or not hasattr(n_windows, "__index__") or operator.index(n_windows) < 1:
            raise ValueError(f"n_windows must be an integer >= 1, got {n_windows!r}")
        n_windows = operator.index(n_windows)
        if round_ not in self.buffers:
            raise KeyError(f"round {round_} has no data; rounds: {self.rounds}")
        if max(self.lengths[round_]) < self.L:
            raise ValueError(f"round {round_} has no trajectory of L={self.L} steps or more to sample windows from; "
                             f"its trajectory lengths: {self.lengths[round_]}")
        with torch.random.fork_rng():
            torch.manual_seed(int(torch.randint(2**62, (), generator=self.generator)))
            sample = self.buffers[round_].sample(batch_size=n_windows * self.L)
        return sample.reshape(n_windows, self.L)

    def all_data(self) -> TensorDictBase:
        """Every transition of every round, concatenated; ``ValueError`` while no trajectory is stored."""
        if not self.buffers:
            raise ValueError("the buffers hold no data yet: add() trajectories before all_data() or a trainer's "
                             "fit_normalization()")
        return torch.cat([self.data(r) for r in self.rounds])

    def save(self, folder: str | Path) -> None:
        """Write every round's buffer and tau to ``folder`` (``rb.dumps`` per round, plus a manifest)."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        for r in self.rounds:
            self.buffers[r].dumps(folder / f"round_{r}")
        for r, tau in self.taus.items():
            tau.memmap(folder / f"tau_{r}")
        for r, drives in self.calibration.items():
            for k, drive in enumerate(drives):
                drive.memmap(folder / f"calibration_{r}_{k}")
        meta = {"L": self.L, "capacity": self.capacity, "n_traj": self.n_traj, "rounds": self.rounds,
                "keys": {"observation_key": self.observation_key, "action_key": self.action_key,
                         "history_key": self.history_key},
                "taus": sorted(self.taus), "calibration": {str(r): len(v) for r, v in self.calibration.items()},
                "generator": self.generator.get_state().tolist(), "n_actions": self.n_actions,
                "storage": self.storage, "device": str(self.device)}
        (folder / "manifest.json").write_text(json.dumps(meta))

    @classmethod
    def load(cls, folder: str | Path, *, device: str | torch.device | None = None,
             transform: Transform | None = None) -> RoundBuffers:
        """Read buffers written by :meth:`save` (on their saved device and storage, or on ``device``)."""
        folder = Path(folder)
        manifest = folder / "manifest.json"
        if not manifest.is_file():
            raise FileNotFoundError(f"no replay-buffer manifest in {str(folder)!r}")
        meta = json.loads(manifest.read_text())
        keys = {name: key if isinstance(key, str) else tuple(key) for name, key in meta.get("keys", {}).items()}
        # keys, n_actions, storage, device: absent in older checkpoints (the defaults)
        out = cls(L=meta["L"], capacity=meta["capacity"], **keys, n_actions=meta.get("n_actions"),
                  storage=meta.get("storage", "memory"), device=device or meta.get("device"), transform=transform)
        out.n_traj = meta["n_traj"]
        out.generator.set_state(torch.tensor(meta["generator"], dtype=torch.uint8))
        for r in meta["rounds"]:
            buffer = out._new_buffer()
            with _quiet_storage():
                buffer.loads(folder / f"round_{r}")
            out.buffers[int(r)] = buffer
            # the lengths from the stored trajectory ids (not in the manifest: older checkpoints lack them)
            out.lengths[int(r)] = torch.unique_consecutive(out.data(int(r))["traj"], return_counts=True)[1].tolist()
        for r in meta["taus"]:
            out.taus[int(r)] = _on(TensorDict.load_memmap(folder / f"tau_{r}").clone(), out.device)
        for r, n in meta.get("calibration", {}).items():  # absent in checkpoints written before calibration
            out.calibration[int(r)] = [_on(TensorDict.load_memmap(folder / f"calibration_{r}_{k}").clone(), out.device)
                                       for k in range(n)]
        return out
