"""The worlds of a batch split over threads (``threads=`` of the world, the engine and the env).

The kernels release the GIL (``nogil``) and a world's episode depends only on its own arrays, so a step
on several threads gives exactly the results of one thread.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

__all__ = ["WorldChunks"]


class WorldChunks:
    """The worlds split into ``threads`` contiguous chunks, and a pool that runs a function on each at
    once; the caller's thread takes the first chunk."""

    def __init__(self, num_worlds: int, threads: int = 1) -> None:
        if not isinstance(threads, (int, np.integer)) or threads < 1:
            raise ValueError(f"threads must be an int >= 1, got {threads!r}")
        bounds = np.linspace(0, num_worlds, min(int(threads), num_worlds) + 1).astype(int)
        self.slices = [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]
        self.threads = len(self.slices)
        self._pool: ThreadPoolExecutor | None = None

    def run(self, fn, worlds: np.ndarray | None = None) -> None:
        """``fn(chunk)`` for every chunk (a slice of the worlds) that holds one of ``worlds`` (a bool
        mask (B,); None: every chunk), at once; the first error is raised once every chunk has
        finished. A lone busy chunk (a world being reset) runs on the caller's thread: waking a worker
        costs more than the few worlds it would take."""
        busy = self.slices if worlds is None else [w for w in self.slices if worlds[w].any()]
        if len(busy) <= 1:
            for w in busy:
                fn(w)
            return
        if self._pool is None:
            self._pool = ThreadPoolExecutor(self.threads - 1, thread_name_prefix="catmip-worlds")
        futures = [self._pool.submit(fn, w) for w in busy[1:]]
        try:
            fn(busy[0])
        finally:
            for future in futures:
                future.result()
