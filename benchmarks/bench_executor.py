"""Evaluation decisions: AmatExecutor on FastAmat (the batch-1 runtime) against the padded torch batch.

    python benchmarks/bench_executor.py [--events 25] [--model paper] [--out benchmarks/results/executor.json]

``catmip eval`` / ``bench paper`` / ``render`` play AMAT's argmax decisions through
``catmip_rl.amat.onboard.execution.AmatExecutor``: by default one neighbourhood at a time on FastAmat, as a
robot-side coordinator would; ``fast=False`` runs one padded torch batch of every live world's
neighbourhoods. This script times both on the same engine states, pair by pair, one thread: per
setting (Task 2 with 64 worlds, full communication and sigma = 2; Task 3 with 32 worlds, full
communication), ``--events`` decision events of an evaluation batch (activation (0, 0)), each decided
by both executors (in alternating order) and stepped with FastAmat's actions. Reports the median
milliseconds per event of each, their paired ratio and how many robot decisions were the same (all of
them, or the fast path is wrong). Writes JSON and a PNG next to it.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import torch
from common import cpu_times, machine_info, steal_percent, write_json

from catmip_env.config import make_config
from catmip_env.engines.events import EventEngine
from catmip_rl.amat.onboard.execution import AmatExecutor
from catmip_rl.store.checkpoint import load_model
from catmip_rl.store.files import atomic_savefig

SETTINGS = (  # (label, preset, communication range, worlds)
    ("task2-full", "task2", None, 64),
    ("task2-sigma2", "task2", 2.0, 64),
    ("task3-full", "task3", None, 32),
)


def time_setting(model, preset: str, sigma: float | None, worlds: int, events: int, seed: int) -> dict:
    cfg = make_config(preset, comm_sigma=sigma, activation=(0, 0))
    engine = EventEngine(cfg, worlds, seed, goal_mode="window")
    fast, slow = AmatExecutor(model), AmatExecutor(model, fast=False)
    engine.reset()
    fast_ms, torch_ms, same, decided = [], [], 0, 0
    for k in range(events):
        if engine.state.done.all():
            break
        order = (fast, slow) if k % 2 == 0 else (slow, fast)
        out = {}
        for ex in order:
            t0 = time.perf_counter()
            out[ex is fast] = ex.act(engine)
            (fast_ms if ex is fast else torch_ms).append(1e3 * (time.perf_counter() - t0))
        active = engine.active & ~engine.state.done[:, None]
        decided += int(active.sum())
        same += int((out[True][active] == out[False][active]).sum())
        engine.step(out[True])
    ratios = [t / f for f, t in zip(fast_ms, torch_ms)]
    return {
        "events": len(fast_ms), "decisions": decided, "same_actions": same,
        "fast_ms": statistics.median(fast_ms), "torch_ms": statistics.median(torch_ms),
        "torch_over_fast": statistics.median(ratios),
    }  # fmt: skip


def plot(results: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.2))
    x = np.arange(len(results))
    ax.bar(x - 0.2, [r["fast_ms"] for r in results], 0.4, label="FastAmat, per neighbourhood (default)")
    ax.bar(x + 0.2, [r["torch_ms"] for r in results], 0.4, label="torch, padded batch (fast=False)")
    ax.set_xticks(x, [f"{r['setting']}\n{r['worlds']} worlds" for r in results])
    ax.set_ylabel("ms per decision event (median)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=120)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--events", type=int, default=25, help="decision events timed per setting")
    ap.add_argument("--model", default="paper", help="a shipped model's name or a model file")
    ap.add_argument("--seed", type=int, default=0, help="the evaluation batch's map seed")
    ap.add_argument("--out", default="benchmarks/results/executor.json")
    args = ap.parse_args()
    torch.set_num_threads(1)
    model = load_model(args.model)
    results = []
    before = cpu_times()
    for label, preset, sigma, worlds in SETTINGS:
        r = time_setting(model, preset, sigma, worlds, args.events, args.seed)
        results.append({"setting": label, "worlds": worlds, **r})
        print(f"{label:>13} ({worlds} worlds, {r['events']} events): FastAmat {r['fast_ms']:.1f} ms, "
              f"torch {r['torch_ms']:.1f} ms per event (x{r['torch_over_fast']:.2f}); "
              f"same actions {r['same_actions']}/{r['decisions']}")  # fmt: skip
    info = machine_info(threads=1, model=args.model, cpu_steal_percent=steal_percent(before, cpu_times()))
    out = write_json(args.out, {"machine": info, "results": results})
    plot(results, out.with_suffix(".png"))
    print(f"wrote {out.with_suffix('.png')}")


if __name__ == "__main__":
    main()
