"""How the cost grows with the map size and the team size (one thread).

    python benchmarks/bench_scaling.py [--seconds 1] [--out benchmarks/results/scaling.json]   # + scaling.png

Two curves, both on the ``task2`` preset (horizon 400, activation (0, 0)) with the map side and team
overridden:

* map size S in 15, 20, 32, 64 with a fixed team of 3 (rescuer, explorer, explorer);
* team size N in 2, 3, 6, 12 on a fixed 32x32 map (1 rescuer + N - 1 explorers; the spawn box holds
  at most 16 robots, so N = 12 fits S = 32).

Per point: world-ticks/s of ``BatchedWorld`` (B = 64, uniformly random primitive actions, resets in the
timed loop, as ``bench_engine.py``), decision events/s of ``EventEngine`` (B = 64, uniformly random valid
window goals, whose drawing is timed apart and excluded, as ``bench_events.py``), and the batch-1 AMAT
decision latency (Table 2 model, every robot active, embed -> encode -> argmax autoregressive decode, as
``bench_amat.py``; median over ``--seconds``) on a real observation (world 0 of the event engine after
10 random decision events, its real action masks). When ``catmip_rl.amat.onboard.fast_amat.FastAmat``
imports, its batch-1 ``decide`` on the same observation is a second curve (its sparse convolution
depends on the map content, so random-noise maps would be unrepresentative).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from common import env_observation, machine_info, plot_scaling_panels, write_json  # noqa: E402

from catmip_env import BatchedWorld, EnvConfig, make_config  # noqa: E402
from catmip_env.engines.events import EventEngine, random_valid_actions  # noqa: E402
from catmip_env.runtime.files import atomic_path  # noqa: E402 (the env benchmark stays torch-free)

MAPS = (15, 20, 32, 64)
TEAMS = (2, 3, 6, 12)
FIXED_TEAM = 3
FIXED_MAP = 32
BASE_PRESET = "task2"


def team_of(n: int) -> tuple[str, ...]:
    """1 rescuer + n - 1 explorers."""
    return ("rescuer",) + ("explorer",) * (n - 1)


def env_config(map_size: int, robots: int) -> EnvConfig:
    return make_config(BASE_PRESET, map_size=map_size, team=team_of(robots))


class Clocks:
    """Wall time and this process's CPU time since creation (CPU time is steadier on a shared machine:
    another process's work shows in the wall clock only)."""

    def __init__(self) -> None:
        self.wall, self.cpu = time.perf_counter(), time.process_time()

    def elapsed(self) -> tuple[float, float]:
        return time.perf_counter() - self.wall, time.process_time() - self.cpu


def engine_rate(cfg: EnvConfig, num_worlds: int, seconds: float) -> dict[str, float]:
    """World-ticks per wall second and per CPU second of the primitive engine, random actions."""
    eng = BatchedWorld(cfg, num_worlds, seed=0)
    eng.reset()
    pool = np.random.default_rng(0).integers(0, 4, size=(64, num_worlds, eng.num_robots))
    for k in range(20):
        eng.step(pool[k % 64])
    ticks = steps = 0
    clocks = Clocks()
    while True:
        ticks += num_worlds - int(eng.state.done.sum())
        eng.step(pool[steps % 64])
        steps += 1
        if eng.state.done.any():
            eng.reset(worlds=eng.state.done)
        if steps % 16 == 0 and time.perf_counter() - clocks.wall > seconds:
            break
    wall, cpu = clocks.elapsed()
    return {"engine_world_ticks_per_s": ticks / wall, "engine_world_ticks_per_cpu_s": ticks / cpu}


def event_rates(cfg: EnvConfig, num_worlds: int, seconds: float) -> dict[str, float]:
    """Decision events and world-ticks per second (wall and CPU) of the event engine under random
    valid window goals; drawing the goals is timed apart and excluded."""
    eng = EventEngine(cfg.replace(activation=(0, 0)), num_worlds, seed=0)
    eng.reset()
    rng = np.random.default_rng(0)

    def goals() -> np.ndarray:
        return random_valid_actions(eng.masks, rng)

    for _ in range(20):
        eng.step(goals())
        if eng.state.done.any():
            eng.reset(worlds=eng.state.done)
    ticks = events = 0
    policy_wall = policy_cpu = 0.0
    clocks = Clocks()
    while time.perf_counter() - clocks.wall < seconds:
        policy = Clocks()
        a = goals()
        w, c = policy.elapsed()
        policy_wall, policy_cpu = policy_wall + w, policy_cpu + c
        events += num_worlds - int(eng.state.done.sum())
        ticks += int(eng.step(a).event_ticks.sum())
        if eng.state.done.any():
            eng.reset(worlds=eng.state.done)
    wall, cpu = clocks.elapsed()
    wall, cpu = wall - policy_wall, cpu - policy_cpu
    return {
        "events_per_s": events / wall,
        "events_per_cpu_s": events / cpu,
        "event_world_ticks_per_s": ticks / wall,
    }


def median_ms(
    fn: Callable[[], Any], seconds: float, warmup: int = 5, min_repeats: int = 5
) -> tuple[float, float]:
    """Median wall time and median CPU time of ``fn`` in ms over about ``seconds`` of calls."""
    for _ in range(warmup):
        fn()
    walls: list[float] = []
    cpus: list[float] = []
    start = time.perf_counter()
    while len(walls) < min_repeats or time.perf_counter() - start < seconds:
        clocks = Clocks()
        fn()
        w, c = clocks.elapsed()
        walls.append(w)
        cpus.append(c)
    return 1000 * statistics.median(walls), 1000 * statistics.median(cpus)


class AmatTimer:
    """Batch-1 decision latency of the torch AMAT and, when importable, of ``FastAmat``."""

    def __init__(self) -> None:
        import torch

        from catmip_rl.amat.model import AMAT

        self.torch = torch
        torch.set_num_threads(1)
        torch.manual_seed(0)
        self.model = AMAT().eval()
        self.fast: Any = None
        self.fast_note = ""
        try:
            from catmip_rl.amat.onboard.fast_amat import FastAmat  # written in parallel; optional
        except Exception as exc:  # noqa: BLE001 - missing module or a broken import: skip the curve
            self.fast_note = f"FastAmat (catmip_rl.amat.onboard) not available ({type(exc).__name__}: {exc})"
        else:
            try:
                self.fast = FastAmat.from_model(self.model)
            except Exception as exc:  # noqa: BLE001
                self.fast_note = f"FastAmat.from_model failed ({type(exc).__name__}: {exc})"

    def torch_ms(self, x: dict[str, np.ndarray], seconds: float) -> tuple[float, float]:
        from catmip_rl.amat.model import decision_order

        t = {k: self.torch.from_numpy(v)[None] for k, v in x.items()}  # batch of 1
        obs = {k: t[k] for k in ("global_map", "local_map", "agent_class")}
        order, model = decision_order(t["active"]), self.model

        def decide() -> Any:
            with self.torch.inference_mode():
                rep, _ = model.encode(model.embed(obs))
                return model.decode_autoregressive(
                    rep, t["action_mask"], order, t["active"], obs["agent_class"], deterministic=True
                )

        return median_ms(decide, seconds)

    def fast_ms(self, x: dict[str, np.ndarray], seconds: float) -> tuple[float, float] | tuple[None, None]:
        if self.fast is None:
            return None, None
        try:
            self.fast.decide(**x, deterministic=True)  # compiles on the first call (numba cache)
        except Exception as exc:  # noqa: BLE001 - the module is being written: skip, with the reason
            self.fast_note = f"FastAmat.decide failed ({type(exc).__name__}: {exc})"
            self.fast = None
            return None, None
        return median_ms(lambda: self.fast.decide(**x, deterministic=True), seconds)


def measure(map_size: int, robots: int, args: argparse.Namespace, amat: AmatTimer | None) -> dict:
    cfg = env_config(map_size, robots)
    row: dict[str, Any] = {"map": map_size, "robots": robots, "team": list(cfg.team)}
    row |= engine_rate(cfg, args.num_worlds, args.seconds)
    row |= event_rates(cfg, args.num_worlds, args.seconds)
    row["amat_ms"] = row["amat_cpu_ms"] = row["fast_amat_ms"] = row["fast_amat_cpu_ms"] = None
    if amat is not None:
        x = env_observation(cfg)
        row["amat_ms"], row["amat_cpu_ms"] = amat.torch_ms(x, args.seconds)
        row["fast_amat_ms"], row["fast_amat_cpu_ms"] = amat.fast_ms(x, args.seconds)
    fast = f", FastAmat {row['fast_amat_ms']:.2f} ms" if row["fast_amat_ms"] is not None else ""
    lat = f"AMAT {row['amat_ms']:.2f} ms" if row["amat_ms"] is not None else "AMAT skipped"
    print(
        f"S={map_size:2d} N={robots:2d}: engine {row['engine_world_ticks_per_s']:>9,.0f} ticks/s "
        f"({row['engine_world_ticks_per_cpu_s']:,.0f} per CPU-s), events {row['events_per_s']:>8,.0f}/s "
        f"({row['events_per_cpu_s']:,.0f} per CPU-s), {lat}{fast}",
        flush=True,
    )
    return row


def best_of(a: dict, b: dict) -> dict:
    """Per field the better of two measurements of a point: the higher rate, the lower latency."""
    out = dict(a)
    for k, v in b.items():
        if v is None or a.get(k) is None:
            out[k] = a.get(k) if v is None else v
        elif "_per_" in k:
            out[k] = max(a[k], v)
        elif k.endswith("_ms"):
            out[k] = min(a[k], v)
    return out


def plot(results: dict, path: Path) -> None:
    """2x2 panels: engine rates and AMAT latency against map size and team size."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(10, 7.5))
    plot_scaling_panels(axes, results["curves"], results["settings"]["num_worlds"])
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=1.0, help="timed seconds per measurement")
    ap.add_argument("--maps", type=int, nargs="+", default=list(MAPS), help="map sides (team of 3)")
    ap.add_argument("--teams", type=int, nargs="+", default=list(TEAMS), help="team sizes (32x32 map)")
    ap.add_argument("--num-worlds", type=int, default=64)
    ap.add_argument("--rounds", type=int, default=1, help="measure every point this often, keep the best")
    ap.add_argument("--no-amat", action="store_true", help="skip the AMAT latency curves")
    ap.add_argument("--out", default="benchmarks/results/scaling.json")
    args = ap.parse_args(argv)

    amat = None
    note = ""
    if not args.no_amat:
        try:
            amat = AmatTimer()
        except ImportError as exc:  # torch is the rl extra
            note = f"AMAT curves skipped: {exc}"
    results: dict[str, Any] = {
        "machine": machine_info(load_average_start=list(os.getloadavg())),
        "settings": {
            "base_preset": BASE_PRESET,
            "num_worlds": args.num_worlds,
            "seconds": args.seconds,
            "rounds": args.rounds,
            "fixed_team": list(team_of(FIXED_TEAM)),
            "fixed_map": FIXED_MAP,
            "threads": 1,
            "amat_input": "world 0 of an EventEngine after 10 random decision events, every robot active",
        },
        "curves": {"map_size": [], "team_size": []},
    }
    if amat is not None:
        results["machine"]["torch"] = amat.torch.__version__
    points = [("map_size", s, FIXED_TEAM) for s in args.maps] + [
        ("team_size", FIXED_MAP, n) for n in args.teams
    ]
    best: dict[tuple, dict] = {}
    for r in range(args.rounds):  # rounds interleave the points: slow spells of a shared CPU spread out
        if args.rounds > 1:
            print(f"round {r + 1}/{args.rounds}", flush=True)
        for axis, s, n in points:
            row = measure(s, n, args, amat)
            best[axis, s, n] = best_of(best[axis, s, n], row) if (axis, s, n) in best else row
    for axis, s, n in points:
        results["curves"][axis].append(best[axis, s, n])
    if amat is not None:
        note = amat.fast_note
    results["machine"]["load_average_end"] = list(os.getloadavg())
    results["fast_amat"] = {
        "available": any(r["fast_amat_ms"] is not None for c in results["curves"].values() for r in c),
        "note": note,
    }
    if note:
        print(note)
    out = write_json(args.out, results)
    plot(results, out.with_suffix(".png"))
    print(f"wrote {out.with_suffix('.png')}")
    return results


if __name__ == "__main__":
    main()
