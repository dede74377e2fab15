"""The worlds of a batch split over threads (``threads=`` of the world, the engine and the env).

The kernels release the GIL (``nogil``) and a world's episode depends only on its own arrays, so a step
on several threads gives exactly the results of one thread.

Each extra thread is a worker of its own that waits on a queue for the next chunk: handing a chunk over
and back this way takes about 18 us on a 2-core test machine, against 30 us through a
``ThreadPoolExecutor``'s work items and futures, which a primitive tick of 256 Task-2 worlds (0.85 ms on
one thread) pays at every step.
"""

from __future__ import annotations

import itertools
import os
import queue
import threading
import weakref
from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["WorldChunks"]


_JOB_IDS = itertools.count(1)


def _serve(jobs: queue.SimpleQueue, done: queue.SimpleQueue) -> None:
    """A worker's loop: run each ``(job, fn, chunk)`` it is given, report ``(job, error or None)``; a job
    of None ends the loop. Nothing of a job is kept while it waits for the next (a chunk's function
    holds its world: the world could never be freed)."""
    while True:
        item = jobs.get()
        if item is None:
            return
        job, fn, chunk = item
        error = None
        try:
            fn(chunk)
        except BaseException as raised:  # noqa: BLE001 - handed to the caller, which raises it
            error = raised
        del item, fn, chunk
        done.put((job, error))
        del error


class _Worker:
    """A daemon thread that runs the chunks it is given in order; it ends when its owner is collected."""

    def __init__(self, name: str) -> None:
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._done: queue.SimpleQueue = queue.SimpleQueue()
        self._finished: dict[int, BaseException | None] = {}  # reports read while waiting for another job
        self.thread = threading.Thread(target=_serve, args=(self._jobs, self._done), name=name, daemon=True)
        self.thread.start()
        weakref.finalize(self, self._jobs.put, None)

    def start(self, fn: Callable[[slice], None], chunk: slice) -> int:
        """Give the worker ``fn(chunk)``; the job's id, for :meth:`wait`."""
        job = next(_JOB_IDS)
        self._jobs.put((job, fn, chunk))
        return job

    def wait(self, job: int) -> BaseException | None:
        """Wait for ``job`` to end; its error, if it raised one. An interrupt (Ctrl-C) meanwhile is raised
        once the job has ended: the job is still writing its worlds."""
        interrupted = None
        while job not in self._finished:
            try:
                ended, error = self._done.get()
            except BaseException as raised:  # noqa: BLE001 - raised below, after the job
                interrupted = raised
                continue
            self._finished[ended] = error
        error = self._finished.pop(job)
        if interrupted is not None:
            raise interrupted
        return error


class WorldChunks:
    """The worlds split into ``threads`` contiguous chunks, and workers that run a function on each at
    once; the caller's thread takes the first chunk."""

    def __init__(self, num_worlds: int, threads: int = 1) -> None:
        if not isinstance(threads, (int, np.integer)) or threads < 1:
            raise ValueError(f"threads must be an int >= 1, got {threads!r}")
        bounds = np.linspace(0, num_worlds, min(int(threads), num_worlds) + 1).astype(int)
        self.slices = [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]
        self.threads = len(self.slices)
        self._workers: list[_Worker] = []
        self._pid = 0  # the process the workers run in: a forked child starts its own

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "_workers": []}  # threads are this process's: started again when needed

    def run(self, fn: Callable[[slice], None], worlds: np.ndarray | None = None) -> None:
        """``fn(chunk)`` for every chunk (a slice of the worlds) that holds one of ``worlds`` (a bool
        mask (B,); None: every chunk), at once; the first error is raised once every chunk has
        finished. A lone busy chunk (a world being reset) runs on the caller's thread: waking a worker
        costs more than the few worlds it would take."""
        busy = self.slices if worlds is None else [w for w in self.slices if worlds[w].any()]
        if len(busy) <= 1:
            for w in busy:
                fn(w)
            return
        if not self._workers or self._pid != os.getpid():  # none yet, or a fork's copy of the parent's
            self._workers = [_Worker(f"catmip-worlds-{k}") for k in range(1, self.threads)]
            self._pid = os.getpid()
        if any(threading.current_thread() is worker.thread for worker in self._workers):
            for w in busy:  # called from inside one of this run's chunks: one after another, here
                fn(w)
            return
        started: list[tuple[_Worker, int]] = []
        try:
            for worker, chunk in zip(self._workers, busy[1:]):
                started.append((worker, worker.start(fn, chunk)))
            fn(busy[0])
        finally:
            errors = [worker.wait(job) for worker, job in started]
        for error in errors:
            if error is not None:
                raise error
