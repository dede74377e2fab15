"""What isolation costs: a ``py:`` policy played in-process against the same policy in its worker process.

    python benchmarks/bench_isolation.py [--episodes 100] [--pz-episodes 4] [--repeats 3]
        [--out benchmarks/results/isolation.json]

Every ``py:`` policy plays isolated (``catmip_rl.evaluation.sandbox``: a worker process that holds no
engine); ``isolated=False`` plays it in this process. This script times both on the same maps, one
thread, for Task 2 and Task 3 with sigma = 2 (``EvalSetting("task2", "2")``, ``("task3", "2")``) and the
policies of ``benchmarks/isolation_policies.py``: at the engine level one at a planner's speed
(``nearest``, cell goals) and one at AMAT's (the shipped paper model through ``AmatExecutor``), all
``--episodes`` maps of a setting in one batch; at the PettingZoo level a policy reading the action masks,
one world at a time (``--pz-episodes`` maps, a message per decision).

Each policy is built once each way (``start_s``: the factory; isolated, the worker's start too) and
plays one map first (``warm_s``: the first calls of its kernels, in the worker or here); then the maps
are played (``play_s``, the fastest of ``--repeats`` in alternating order): episodes per second, the
isolated / in-process ratio of ``play_s`` and the cost per ``act`` call (one message each way). The
rescue ticks are checked identical both ways. Writes JSON.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from common import cpu_times, machine_info, steal_percent, write_json

from catmip_env.engines.events import EventEngine
from catmip_env.play import play, plays_one_world_at_a_time
from catmip_rl.evaluation.evaluate import EvalSetting
from catmip_rl.evaluation.methods import make_policy, parse_method
from catmip_rl.evaluation.sandbox import close_policy
from catmip_rl.evaluation.workers import torch_threads

POLICIES = Path(__file__).with_name("isolation_policies.py")
RUNS = (  # (policy factory, level, which --episodes)
    ("planner", "engine", "episodes"),
    ("amat", "engine", "episodes"),
    ("first_allowed", "pettingzoo", "pz_episodes"),
)
SETTINGS = (EvalSetting("task2", "2"), EvalSetting("task3", "2"))
SEED = 1000  # the validation split's maps


def play_maps(policy, cfg, goal_mode: str, episodes: int) -> tuple[float, int, np.ndarray]:
    """(seconds, act calls, rescue ticks) of ``policy`` playing maps 0 .. episodes-1 as ``evaluate``
    plays them: all at once, or one world at a time with ``reset()`` before each."""
    acts = 0

    def act(engine):
        nonlocal acts
        acts += 1
        return policy.act(engine)

    t0 = time.perf_counter()
    if plays_one_world_at_a_time(policy):
        engine = EventEngine(cfg, num_worlds=1, seed=SEED, goal_mode=goal_mode)
        ticks = []
        for e in range(episodes):
            engine.reset(episode_indices=[e])
            policy.reset()
            ticks.append(play(engine, act).rescue_tick)
        ticks = np.concatenate(ticks)
    else:
        engine = EventEngine(cfg, num_worlds=episodes, seed=SEED, goal_mode=goal_mode)
        engine.reset()
        if hasattr(policy, "start_episodes"):
            policy.start_episodes(engine.num_worlds, engine.num_robots)
        ticks = play(engine, act).rescue_tick
    return time.perf_counter() - t0, acts, np.asarray(ticks)


def time_run(factory: str, setting: EvalSetting, episodes: int, repeats: int) -> dict:
    method = parse_method(f"py:{POLICIES}:{factory}")
    cfg = setting.env_config()
    built, start, warm = {}, {}, {}
    try:
        for isolated in (False, True):
            t0 = time.perf_counter()
            policy, goal_mode, _needs = make_policy(replace(method, isolated=isolated), cfg, SEED)
            start[isolated] = time.perf_counter() - t0
            built[isolated] = (policy, goal_mode)
            warm[isolated] = play_maps(policy, cfg, goal_mode, 1)[0]
        seconds: dict[bool, list[float]] = {False: [], True: []}
        played = {}
        for k in range(repeats):
            for isolated in (False, True) if k % 2 == 0 else (True, False):
                policy, goal_mode = built[isolated]
                s, acts, ticks = play_maps(policy, cfg, goal_mode, episodes)
                seconds[isolated].append(s)
                played[isolated] = (acts, ticks.tolist())
    finally:
        for policy, _ in built.values():
            close_policy(policy)
    if played[False] != played[True]:
        raise SystemExit(f"{factory} on {setting.label}: isolated play differs from in-process play")
    here, there, acts = min(seconds[False]), min(seconds[True]), played[False][0]
    return {
        "episodes": episodes, "acts": acts,
        "in_process_start_s": start[False], "isolated_start_s": start[True],
        "in_process_warm_s": warm[False], "isolated_warm_s": warm[True],
        "in_process_s": here, "isolated_s": there,
        "in_process_episodes_per_s": episodes / here, "isolated_episodes_per_s": episodes / there,
        "ratio": there / here, "us_per_act": 1e6 * (there - here) / max(acts, 1),
    }  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--episodes", type=int, default=100, help="maps per engine-level run (one batch)")
    ap.add_argument("--pz-episodes", type=int, default=4, help="maps per PettingZoo-level run")
    ap.add_argument("--repeats", type=int, default=3, help="runs each way (the fastest is reported)")
    ap.add_argument("--out", default="benchmarks/results/isolation.json")
    args = ap.parse_args()
    torch_threads(1)
    results = []
    before = cpu_times()
    for setting in SETTINGS:
        for factory, level, count in RUNS:
            r = time_run(factory, setting, getattr(args, count), args.repeats)
            results.append({"setting": setting.label, "policy": factory, "level": level, **r})
            speeds = f"{r['in_process_episodes_per_s']:.2f} / {r['isolated_episodes_per_s']:.2f} ep/s"
            once = f"worker start {r['isolated_start_s']:.1f} s, first map {r['isolated_warm_s']:.2f} s"
            print(f"{setting.label} {factory} ({level}, {r['episodes']} maps, {r['acts']} acts): "
                  f"in-process / isolated {speeds}, x{r['ratio']:.2f} ({r['us_per_act']:+.0f} us per act; "
                  f"{once} vs {r['in_process_warm_s']:.2f} s here)")  # fmt: skip
    info = machine_info(threads=1, cpu_steal_percent=steal_percent(before, cpu_times()))
    write_json(args.out, {"machine": info, "results": results})


if __name__ == "__main__":
    main()
