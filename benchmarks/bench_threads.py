"""Both engines on several threads: seconds per step of B worlds on 1 thread and on every thread count
up to the cores, the resets of finished worlds included (the random actions are chosen outside the
timing), and a check that every thread count gives the same worlds.

* ``event``: ``EventEngine(threads=k)``, cell goals, random valid goals, one decision event a step;
* ``primitive``: ``BatchedWorld(threads=k)``, random primitive actions, one tick a step; a tick below
  ``TICK_SPLIT_WORK`` (worlds x robots x cells) runs on one thread whatever ``k`` is (``split`` false in
  its row: the two timings are of the same code, and their ratio is the machine's noise).

    python benchmarks/bench_threads.py [--worlds 16 64 256] [--events 200] \
        [--out benchmarks/results/threads.json]

Writes ``--out`` (with the machine, ``common.machine_info``): per engine, task, world count and thread
count, the seconds per step (the best of ``--repeats``) and the speed-up over one thread.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from common import machine_info, write_json  # noqa: E402

from catmip_env import BatchedWorld, EventEngine, make_config  # noqa: E402
from catmip_env.engines.events import random_valid_actions  # noqa: E402
from catmip_env.engines.world import TICK_SPLIT_WORK  # noqa: E402


def run(engine_kind: str, task: str, worlds: int, steps: int, threads: int) -> tuple[float, np.ndarray]:
    """Seconds per step of ``worlds`` worlds on ``threads`` threads (the step and the resets of finished
    worlds; not the random choice) and the final positions (every thread count must give the same)."""
    cfg = make_config(task)
    if engine_kind == "event":
        engine = EventEngine(cfg, num_worlds=worlds, seed=0, goal_mode="cell", threads=threads)
    else:
        engine = BatchedWorld(cfg, num_worlds=worlds, seed=0, threads=threads)
    engine.reset()
    rng = np.random.default_rng(0)
    seconds = 0.0
    for _ in range(steps):
        if engine_kind == "event":
            actions = random_valid_actions(engine.masks, rng)
        else:
            actions = rng.integers(0, 4, size=(worlds, cfg.num_robots))
        t0 = time.perf_counter()
        engine.step(actions)
        if engine.state.done.any():
            engine.reset(worlds=engine.state.done)
        seconds += time.perf_counter() - t0
    return seconds / steps, engine.state.pos.copy()


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--worlds", type=int, nargs="+", default=[16, 64, 256])
    ap.add_argument(
        "--events", type=int, default=200, help="steps a measurement: events (event engine), 5x as many ticks"
    )
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--engines", nargs="+", default=["event", "primitive"], choices=["event", "primitive"])
    ap.add_argument("--out", default="benchmarks/results/threads.json")
    args = ap.parse_args(argv)
    cores = os.cpu_count() or 1
    counts = sorted({1, *range(2, cores + 1)})
    rows = []
    for kind in args.engines:
        steps = args.events * (1 if kind == "event" else 5)  # a tick is much less work than an event
        for task in ("task2", "task3"):
            run(kind, task, 8, 5, max(counts))  # compile (cached) and warm the pool
            cfg = make_config(task)
            for worlds in args.worlds:
                work = worlds * cfg.num_robots * cfg.map_shape[0] * cfg.map_shape[1]
                split = kind == "event" or work >= TICK_SPLIT_WORK
                base, reference = None, None
                for k in counts:
                    timed = [run(kind, task, worlds, steps, k) for _ in range(args.repeats)]
                    best, pos = min(t for t, _ in timed), timed[0][1]
                    reference = pos if reference is None else reference
                    base = best if base is None else base
                    same = bool(np.array_equal(reference, pos))
                    rows.append({"engine": kind, "task": task, "worlds": worlds, "threads": k,
                                 "split": split, "seconds_per_step": best, "speedup": base / best,
                                 "same_worlds_as_one_thread": same})  # fmt: skip
                    print(
                        f"{kind} {task} B={worlds} threads={k}: {1e3 * best:.3f} ms/step, "
                        f"x{base / best:.2f}, same {same}{'' if split else ' (one thread: below the split)'}"
                    )
    out = {"machine": machine_info(cores=cores), "rows": rows}
    write_json(args.out, out)
    return out


if __name__ == "__main__":
    main()
