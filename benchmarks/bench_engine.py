"""World-ticks per second of the batched engine and of the PettingZoo adapter (one thread).

    python benchmarks/bench_engine.py [--seconds 3] [--out benchmarks/results/engine.json]

Every measured tick includes moving, sensing, communication and merging, the mission checks, SLAM
noise when enabled and building every robot's macro-observation; finished worlds are reset inside the
timed loop (map generation included). Actions are uniformly random primitive actions drawn up front.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from common import machine_info, write_json  # noqa: E402

from catmip_env import BatchedWorld, make_config, search_rescue_v0  # noqa: E402

TASKS = ("task1", "task2", "task3")


def bench_engine(preset: str, num_worlds: int, seconds: float, **overrides) -> dict:
    eng = BatchedWorld(make_config(preset, **overrides), num_worlds, seed=0)
    eng.reset()
    rng = np.random.default_rng(0)
    pool = rng.integers(0, 4, size=(64, num_worlds, eng.num_robots))
    for k in range(20):  # warm-up (compilation is cached on disk)
        eng.step(pool[k % 64])
    ticks, steps, resets = 0, 0, 0
    t0 = time.perf_counter()
    while True:
        done = eng.state.done
        live = num_worlds - int(done.sum())
        eng.step(pool[steps % 64])
        ticks += live
        steps += 1
        if eng.state.done.any():
            resets += int(eng.state.done.sum())
            eng.reset(worlds=eng.state.done)
        if steps % 16 == 0 and time.perf_counter() - t0 > seconds:
            break
    dt = time.perf_counter() - t0
    return {
        "preset": preset,
        "num_worlds": num_worlds,
        "overrides": overrides,
        "world_ticks_per_s": ticks / dt,
        "batched_steps_per_s": steps / dt,
        "episodes_reset": resets,
        "seconds": dt,
    }


def bench_pettingzoo(preset: str, seconds: float, **overrides) -> dict:
    env = search_rescue_v0.parallel_env(preset=preset, level="primitive", **overrides)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    pool = [
        {a: int(x) for a, x in zip(env.possible_agents, row)}
        for row in rng.integers(0, 4, (256, len(env.possible_agents)))
    ]
    ticks = 0
    t0 = time.perf_counter()
    while True:
        env.step(pool[ticks % 256])
        ticks += 1
        if not env.agents:
            env.reset()
        if ticks % 32 == 0 and time.perf_counter() - t0 > seconds:
            break
    dt = time.perf_counter() - t0
    return {"preset": preset, "overrides": overrides, "ticks_per_s": ticks / dt, "seconds": dt}


def startup_seconds() -> float:
    """Wall time of a fresh process that imports catmip_env, resets and steps a Task 2 engine."""
    code = (
        "import numpy as np; from catmip_env import BatchedWorld, make_config;"
        "e = BatchedWorld(make_config('task2'), 4, seed=0); e.reset(); e.step(np.zeros((4, 3), int))"
    )
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], check=True)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=3.0, help="timed seconds per measurement")
    ap.add_argument("--out", default="benchmarks/results/engine.json")
    ap.add_argument("--batches", type=int, nargs="+", default=[1, 64, 1024])
    args = ap.parse_args()

    startup_seconds()  # make sure the numba cache is warm
    results: dict = {
        "machine": machine_info(threads=1),
        "startup_s_cached": startup_seconds(),
        "engine": [],
        "pettingzoo": [],
    }
    settings = [{}, {"comm_sigma": 2.0, "slam_noise": 0.05}]
    for preset in TASKS:
        for kw in settings:
            for b in args.batches:
                r = bench_engine(preset, b, args.seconds, **kw)
                results["engine"].append(r)
                rate = r["world_ticks_per_s"]
                print(f"engine  {preset} B={b:5d} {kw or 'full comm'}: {rate:>12,.0f} world-ticks/s")
            r = bench_pettingzoo(preset, args.seconds, **kw)
            results["pettingzoo"].append(r)
            print(f"pettingzoo {preset} B=1 {kw or 'full comm'}: {r['ticks_per_s']:>9,.0f} ticks/s")
    print(f"fresh-process start (cached numba): {results['startup_s_cached']:.2f} s")
    write_json(args.out, results)


if __name__ == "__main__":
    main()
