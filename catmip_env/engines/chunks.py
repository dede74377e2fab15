"""The worlds of a batch split over threads (``threads=`` of the world, the engine and the env).

The kernels release the GIL (``nogil``) and a world's episode depends only on its own arrays, so a step
on several threads gives exactly the results of one thread.

Each extra thread is a worker of its own that waits on a lock for the next chunk: handing a chunk over
and back this way takes about 18 us on a 2-core test machine, against 30 us through a
``ThreadPoolExecutor``'s queue and future, which a primitive tick of 256 Task-2 worlds (0.85 ms on one
thread) pays at every step.
"""

from __future__ import annotations

import os
import threading
import weakref
from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["WorldChunks"]


def _serve(box: list, go: threading.Lock, done: threading.Lock) -> None:
    """A worker's loop: wait for ``go``, run ``box[0](box[1])``, keep its error in ``box[2]``, release
    ``done``; a job of None ends the loop."""
    while True:
        go.acquire()
        fn = box[0]
        if fn is None:
            return
        try:
            fn(box[1])
        except BaseException as error:  # noqa: BLE001 - handed to the caller, which raises it
            box[2] = error
        box[0] = box[1] = None
        done.release()


def _stop(box: list, go: threading.Lock) -> None:
    box[0] = None
    go.release()


class _Worker:
    """A daemon thread that runs one chunk at a time; it ends when its owner is collected."""

    def __init__(self, name: str) -> None:
        self._box: list[Any] = [None, None, None]
        self._go, self._done = threading.Lock(), threading.Lock()
        self._go.acquire()
        self._done.acquire()
        args = (self._box, self._go, self._done)
        threading.Thread(target=_serve, args=args, name=name, daemon=True).start()
        weakref.finalize(self, _stop, self._box, self._go)

    def start(self, fn: Callable[[slice], None], chunk: slice) -> None:
        self._box[:] = [fn, chunk, None]
        self._go.release()

    def wait(self) -> BaseException | None:
        """Wait for the chunk started last; its error, if it raised one."""
        self._done.acquire()
        error, self._box[2] = self._box[2], None
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
        started = list(zip(self._workers, busy[1:]))
        for worker, chunk in started:
            worker.start(fn, chunk)
        errors: list[BaseException | None] = []
        try:
            fn(busy[0])
        finally:
            errors = [worker.wait() for worker, _ in started]
        for error in errors:
            if error is not None:
                raise error
