"""One job runner, two back ends: a function mapped over items on this machine's processes or on a Ray
cluster, the same results either way. ``catmip bench suite``, ``bench paper`` and the leaderboard's
checks send their work through it (``--backend local|ray``, ``--ray-address``).

    runner = Runner("ray", workers=16, ray_address="auto")
    results = runner.map(play_chunk, chunks, weights, on_done=write_when_complete)

* **local**: one worker plays in this process; more play in a pool of spawned processes (no state
  shared) that die with this one. A pool broken by a lost worker is started again for the items left,
  until :data:`POOL_BREAKS` pools in a row end none.
* **ray**: each item is a Ray task (``@ray.remote``, one CPU; the stable task API of Ray >= 2.40), at
  most ``workers`` of them in flight (:mod:`catmip_rl.adapters.ray_tasks`, where Ray is imported);
  Ray retries a task whose worker died (:data:`~catmip_rl.adapters.ray_tasks.RAY_RETRIES`).
  ``ray_address`` None starts a private cluster on loopback (stopped at the end); ``auto`` or
  HOST:PORT joins a running one (as ``catmip train --collector ray`` does). Interrupted, the driver
  cancels its tasks; killed, Ray ends them (a job's tasks die with its driver).

Results come back in the items' order whatever order they finished in; ``on_done(k, result)`` is called
in this process as each finishes (a caller writes what is complete, so that an interrupted run resumes).
The bar counts items weighted by their cost, so its time left holds across tasks of unequal size.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any

from catmip_rl.evaluation.evaluate import progress_bar
from catmip_rl.evaluation.workers import die_with_parent

__all__ = ["Runner", "BACKENDS", "POOL_BREAKS"]

BACKENDS = ("local", "ray")
POOL_BREAKS = 3
"""Local pools broken in a row, none ending an item, before the runner gives up."""


@dataclass(frozen=True)
class Runner:
    """Where a job's items are played: ``backend`` "local" or "ray", on ``workers`` processes (Ray: tasks
    in flight), ``ray_address`` the cluster to join (None: a private one on loopback)."""

    backend: str = "local"
    workers: int = 1
    ray_address: str | None = None

    def __post_init__(self) -> None:
        if self.backend not in BACKENDS:
            raise ValueError(f"backend must be one of {', '.join(BACKENDS)}, got {self.backend!r}")
        if not isinstance(self.workers, int) or self.workers < 1:
            raise ValueError(f"workers must be an int >= 1, got {self.workers!r}")
        if self.ray_address is not None and self.backend != "ray":
            raise ValueError("--ray-address is for --backend ray")

    def map(
        self,
        fn: Callable[[Any], Any],
        items: Sequence[Any],
        weights: Sequence[float] | None = None,
        on_done: Callable[[int, Any], None] | None = None,
        progress: bool = False,
        desc: str = "",
        unit: str = "chunks",
        on_error: Callable[[int, BaseException], Any] | None = None,
        shared: tuple[Callable[[Any], tuple[Any, Any]], Callable[[Any, Any], Any]] | None = None,
    ) -> list[Any]:
        """``fn(item)`` of every item (``fn`` a module-level function, ``items`` picklable), in order.
        ``on_error(k, err)``: on Ray, the result of an item whose task failed for good (its worker died
        past :data:`~catmip_rl.adapters.ray_tasks.RAY_RETRIES`), instead of raising. ``shared``: on Ray, a
        payload many items carry is sent once (:func:`~catmip_rl.adapters.ray_tasks.ray_map`)."""
        weights = list(weights) if weights is not None else [1.0] * len(items)
        bar = _Bar(weights, progress, desc, unit)
        results: dict[int, Any] = {}

        def done(k: int, result: Any) -> None:
            results[k] = result
            if on_done is not None:
                on_done(k, result)
            bar.add(k)

        try:
            if self.backend == "ray":
                from catmip_rl.adapters.ray_tasks import ray_map  # Ray lives in the adapters

                ray_map(fn, items, done, self.workers, self.ray_address, on_error, shared)
            elif self.workers <= 1 or len(items) <= 1:
                for k, item in enumerate(items):
                    done(k, fn(item))
            else:
                _pool_map(fn, items, done, self.workers)
        finally:
            bar.close()
        return [results[k] for k in range(len(items))]


class _Bar:
    def __init__(self, weights: list[float], progress: bool, desc: str, unit: str) -> None:
        self.weights, self.desc, self.unit, self.count = weights, desc, unit, 0
        self.bar = progress_bar(len(weights), desc, progress, unit=unit, leave=True)
        if self.bar is not None:
            self.bar.total = sum(weights)
            self.bar.bar_format = "{desc}: {percentage:3.0f}%|{bar}| [{elapsed}<{remaining}]"
            self.bar.set_description_str(f"{desc} 0/{len(weights)} {unit}")

    def add(self, k: int) -> None:
        self.count += 1
        if self.bar is not None:
            self.bar.set_description_str(
                f"{self.desc} {self.count}/{len(self.weights)} {self.unit}", refresh=False
            )
            self.bar.update(self.weights[k])

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _pool_map(fn, items, done, workers: int) -> None:
    """Play ``items`` on a pool of ``workers`` spawned processes. A pool broken by a lost worker is
    started again for the items left, as long as each pool ends at least one item: :data:`POOL_BREAKS`
    pools in a row that end none raise, naming what is left."""
    left, breaks = list(range(len(items))), 0
    while left:
        spawn = multiprocessing.get_context("spawn")
        pool = ProcessPoolExecutor(
            workers, mp_context=spawn, initializer=die_with_parent, initargs=(os.getpid(),)
        )
        futures = {pool.submit(fn, items[k]): k for k in left}
        try:
            pending = set(futures)
            while pending:
                finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                for future in finished:
                    k = futures[future]
                    done(k, future.result())
                    left.remove(k)
                    breaks = 0
            pool.shutdown(wait=True)
        except BrokenProcessPool:
            _stop(pool)
            breaks += 1
            if breaks >= POOL_BREAKS:
                raise ChildProcessError(  # an OSError: one line from the CLI
                    f"worker processes died {breaks} times in a row with {len(left)} of {len(items)} items "
                    "left and none ended (out of memory? killed?)"
                ) from None
        except BaseException:
            _stop(pool)  # stop the workers now: the pool's exit would wait for their items
            raise


def _stop(pool: ProcessPoolExecutor) -> None:
    for worker in list((getattr(pool, "_processes", None) or {}).values()):
        worker.terminate()
    pool.shutdown(wait=True, cancel_futures=True)
