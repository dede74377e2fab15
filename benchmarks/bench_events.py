"""Decision events and world-ticks per second of the event engine and the PettingZoo macro adapter,
and the planning time per decision of every baseline (one thread).

    python benchmarks/bench_events.py [--seconds 3] [--out benchmarks/results/events.json]

Event engine: uniformly random *valid* window goals (drawn with one vectorised argmax; its cost is
measured and reported apart), the low-level planner, activation and event-time observation and mask
building included; finished worlds are reset inside the timed loop. Activation: the presets'
evaluation rule (0, 0) and the training rule (2, 5).
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from common import machine_info, write_json  # noqa: E402

from catmip_env import make_config, search_rescue_v0  # noqa: E402
from catmip_env.engines.events import EventEngine, random_valid_actions  # noqa: E402
from catmip_env.planners.baselines import PLANNERS, make_planner  # noqa: E402

TASKS = ("task1", "task2", "task3")


def bench_engine(preset: str, num_worlds: int, seconds: float, activation) -> dict:
    eng = EventEngine(make_config(preset, activation=activation), num_worlds, seed=0)
    eng.reset()
    rng = np.random.default_rng(0)
    for _ in range(20):
        eng.step(random_valid_actions(eng.masks, rng))
        if eng.state.done.any():
            eng.reset(worlds=eng.state.done)
    ticks = events = decisions = 0
    policy_s = 0.0
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        t1 = time.perf_counter()
        a = random_valid_actions(eng.masks, rng)
        policy_s += time.perf_counter() - t1
        live = ~eng.state.done
        decisions += int((eng.active & live[:, None]).sum())
        ev = eng.step(a)
        ticks += int(ev.event_ticks.sum())
        events += int(live.sum())
        if eng.state.done.any():
            eng.reset(worlds=eng.state.done)
    dt = time.perf_counter() - t0
    engine_s = dt - policy_s
    return {
        "preset": preset,
        "num_worlds": num_worlds,
        "activation": list(activation),
        "world_ticks_per_s": ticks / engine_s,
        "events_per_s": events / engine_s,
        "decisions_per_s": decisions / engine_s,
        "ticks_per_event": ticks / max(events, 1),
        "policy_share": policy_s / dt,
        "seconds": dt,
    }


def bench_pettingzoo(preset: str, seconds: float, activation) -> dict:
    env = search_rescue_v0.parallel_env(preset=preset, activation=activation)
    obs, infos = env.reset(seed=0)
    rng = np.random.default_rng(0)
    ticks = events = 0
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        masks = np.stack([obs[a]["action_mask"] for a in env.agents])
        acts = dict(zip(env.agents, random_valid_actions(masks, rng).tolist()))
        obs, _, _, _, infos = env.step(acts)
        ticks += infos["robot_0"]["event_ticks"]
        events += 1
        if not env.agents:
            obs, infos = env.reset()
    dt = time.perf_counter() - t0
    return {
        "preset": preset,
        "activation": list(activation),
        "world_ticks_per_s": ticks / dt,
        "events_per_s": events / dt,
        "seconds": dt,
    }


def bench_planner(name: str, preset: str, decisions: int) -> dict:
    eng = EventEngine(make_config(preset), 8, seed=1, goal_mode="cell")
    planner = make_planner(name, seed=0)
    eng.reset()
    planner.act(eng)  # compile
    n, spent = 0, 0.0
    while n < decisions:
        live = ~eng.state.done
        k = int((eng.active & live[:, None]).sum())
        t0 = time.perf_counter()
        a = planner.act(eng)
        spent += time.perf_counter() - t0
        n += k
        eng.step(a)
        if eng.state.done.any():
            eng.reset(worlds=eng.state.done)
    return {"planner": name, "preset": preset, "ms_per_decision": 1000 * spent / n, "decisions": n}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--decisions", type=int, default=400, help="decisions timed per planner")
    ap.add_argument("--out", default="benchmarks/results/events.json")
    args = ap.parse_args()
    results: dict = {
        "machine": machine_info(),
        "engine": [],
        "pettingzoo": [],
        "planners": [],
    }
    for preset in TASKS:
        for activation in ((0, 0), (2, 5)):
            for b in (1, 64):
                r = bench_engine(preset, b, args.seconds, activation)
                results["engine"].append(r)
                print(
                    f"events {preset} B={b:3d} act={activation}: {r['world_ticks_per_s']:>10,.0f} ticks/s "
                    f"{r['events_per_s']:>9,.0f} events/s ({r['ticks_per_event']:.2f} ticks/event)"
                )
            r = bench_pettingzoo(preset, args.seconds, activation)
            results["pettingzoo"].append(r)
            print(
                f"pettingzoo macro {preset} act={activation}: {r['world_ticks_per_s']:>8,.0f} ticks/s "
                f"{r['events_per_s']:>7,.0f} events/s"
            )
    for name in PLANNERS:
        r = bench_planner(name, "task3", args.decisions)
        results["planners"].append(r)
        print(f"planner {name:16s} task3: {r['ms_per_decision']:.3f} ms/decision")
    write_json(args.out, results)


if __name__ == "__main__":
    main()
