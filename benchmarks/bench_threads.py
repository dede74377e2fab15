"""The engine on several threads (``EventEngine(threads=k)``): seconds per event step of B worlds with
random valid goals (the step and the resets; the random choice is not timed), from 1 thread to every
core, and a check that every thread count gives the same worlds. Resets (map generation, per world in
Python) stay on one thread.

    python benchmarks/bench_threads.py [--worlds 64] [--events 200] [--out benchmarks/results/threads.json]

Writes ``--out`` (with the machine, ``common.machine_info``): per task and thread count, the
seconds per event step (the best of ``--repeats``) and the speed-up over one thread.
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

from catmip_env import EventEngine, make_config  # noqa: E402
from catmip_env.events import random_valid_actions  # noqa: E402


def run(task: str, worlds: int, events: int, threads: int) -> tuple[float, np.ndarray]:
    """Seconds per event step of ``worlds`` worlds on ``threads`` threads (the engine's step and the
    resets of finished worlds; not the random policy's choice), and the final goals (to check that the
    thread count changes nothing)."""
    engine = EventEngine(make_config(task), num_worlds=worlds, seed=0, goal_mode="cell", threads=threads)
    engine.reset()
    rng = np.random.default_rng(0)
    seconds = 0.0
    for _ in range(events):
        actions = random_valid_actions(engine.masks, rng)
        t0 = time.perf_counter()
        engine.step(actions)
        if engine.state.done.any():
            engine.reset(worlds=engine.state.done)
        seconds += time.perf_counter() - t0
    return seconds / events, engine.state.goal.copy()


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--worlds", type=int, default=64)
    ap.add_argument("--events", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default="benchmarks/results/threads.json")
    args = ap.parse_args(argv)
    cores = os.cpu_count() or 1
    counts = sorted({1, *range(2, cores + 1)})
    rows = []
    for task in ("task2", "task3"):
        run(task, args.worlds, 5, max(counts))  # compile (cached) and warm the pool
        base, reference = None, None
        for k in counts:
            timed = [run(task, args.worlds, args.events, k) for _ in range(args.repeats)]
            best, goals = min(t for t, _ in timed), timed[0][1]
            reference = goals if reference is None else reference
            base = best if base is None else base
            same = bool(np.array_equal(reference, goals))
            rows.append({"task": task, "worlds": args.worlds, "threads": k, "seconds_per_event": best,
                         "speedup": base / best, "same_worlds_as_one_thread": same})  # fmt: skip
            ms = 1e3 * best
            print(f"{task} B={args.worlds} threads={k}: {ms:.2f} ms/event, x{base / best:.2f}, same {same}")
    out = {"machine": machine_info(cores=cores), "rows": rows}
    write_json(args.out, out)
    return out


if __name__ == "__main__":
    main()
