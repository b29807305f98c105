r"""Where independent work runs: in this process, in a pool of processes, or on a Ray cluster.

What runs is a picklable function of a picklable item (a study's episodes are
:class:`pernav.study.episodes.EpisodeJob`\ s), so it can be shipped anywhere and gives the same result everywhere:
each worker uses one torch thread and every seed is part of the item.

Example:
    >>> ex = make_executor(workers=1)
    >>> ex.map(abs, [-1, 2, -3])
    [1, 2, 3]
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import threading
import time
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import torch
from tqdm.auto import tqdm

__all__ = ["PoolExecutor", "RayExecutor", "SerialExecutor", "init_worker", "make_executor"]


def _exit_with(parent: int, poll_s: float) -> None:
    while os.getppid() == parent:
        time.sleep(poll_s)
    os._exit(1)  # the parent is gone (killed): nobody will read this worker's results


def _one_thread() -> None:
    torch.set_num_threads(1)
    logging.getLogger("torchrl").setLevel(logging.WARNING)


def init_worker(parent: int | None = None, poll_s: float = 1.0) -> None:
    """A pool worker's initializer: one torch thread, quiet torchrl, and exit within ``poll_s`` seconds once
    the parent process ``parent`` is gone (a killed ``pernav study`` would otherwise leave its workers computing).
    The pool passes its own pid: a worker that starts after its parent was killed would read ``os.getppid()``
    as 1 (init) and wait forever."""
    _one_thread()
    parent = os.getppid() if parent is None else parent
    if os.getppid() != parent:  # already orphaned before this initializer ran
        os._exit(1)
    threading.Thread(target=_exit_with, args=(parent, poll_s), daemon=True).start()


def _bar(items: Iterable[Any], desc: str | None, total: int | None = None) -> Iterable[Any]:
    return tqdm(items, desc=desc, total=total, leave=False, disable=desc is None)


class SerialExecutor:
    """Runs everything here, in order."""

    workers = 1

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any], desc: str | None = None) -> list[Any]:
        items = list(items)
        return [fn(x) for x in _bar(items, desc)]

    def close(self) -> None:
        pass


class PoolExecutor:
    """A pool of ``workers`` spawned processes (kept for the executor's life)."""

    def __init__(self, workers: int) -> None:
        self.workers = workers
        self.pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                                        initializer=init_worker, initargs=(os.getpid(),))

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any], desc: str | None = None) -> list[Any]:
        items = list(items)
        return list(_bar(self.pool.map(fn, items), desc, len(items)))

    def close(self) -> None:
        self.pool.shutdown()


class RayExecutor:
    """Ray tasks (one CPU each) on the cluster ``ray.init`` connected to."""

    def __init__(self) -> None:
        import ray  # lazy: an optional dependency (pernav[ray])

        self.ray = ray
        self.workers = int(ray.cluster_resources().get("CPU", 1))
        self._remote = ray.remote(num_cpus=1)(_call)

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any], desc: str | None = None) -> list[Any]:
        refs = [self._remote.remote(fn, x) for x in items]
        return self.ray.get(refs)

    def close(self) -> None:
        pass


def _call(fn: Callable[[Any], Any], item: Any) -> Any:
    _one_thread()  # a Ray task: Ray owns the worker's life
    return fn(item)


def make_executor(workers: int = 1, ray: bool = False) -> SerialExecutor | PoolExecutor | RayExecutor:
    """Ray tasks, a process pool (``workers > 1``), or this process."""
    if ray:
        return RayExecutor()
    return PoolExecutor(workers) if workers > 1 else SerialExecutor()
