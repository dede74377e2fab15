"""Helpers shared by the benchmark scripts."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from catmip_env import EnvConfig
from catmip_env.engines.events import EventEngine, random_valid_actions
from catmip_env.runtime.files import atomic_path
from catmip_env.runtime.machine import machine_info  # noqa: F401  (the benchmarks import it from here)


def cpu_times() -> tuple[int, int] | None:
    """(steal, total) CPU jiffies of the machine so far (Linux /proc/stat), or None elsewhere: the
    difference over a measurement gives the share of CPU time the hypervisor gave to other guests."""
    try:
        fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]
    except OSError:
        return None
    values = [int(v) for v in fields]
    return (values[7] if len(values) > 7 else 0), sum(values[:8])


def steal_percent(before: tuple[int, int] | None, after: tuple[int, int] | None) -> float | None:
    """CPU steal between two ``cpu_times()`` readings, in percent of all CPU time (None if unknown)."""
    if before is None or after is None or after[1] <= before[1]:
        return None
    return 100.0 * (after[0] - before[0]) / (after[1] - before[1])


def write_json(path: str | Path, results: Any) -> Path:
    """Write results as JSON atomically (``catmip_env.runtime.files.atomic_path``) and say where."""
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(results, indent=2))
    print(f"wrote {path}")
    return path


def env_observation(cfg: EnvConfig, events: int = 10) -> dict[str, np.ndarray]:
    """One world's macro-observation (numpy, no batch axis) after ``events`` random decision events,
    every robot marked active: real maps (rooms, explored area, merged beliefs), real action masks."""
    eng = EventEngine(cfg.replace(activation=(0, 0)), 1, seed=0)
    eng.reset()
    rng = np.random.default_rng(0)
    for _ in range(events):
        eng.step(random_valid_actions(eng.masks, rng))
        if eng.state.done[0]:
            eng.reset()
    return {
        "global_map": eng.obs_global[0].copy(),  # (N, 5+C, S, S) uint8
        "local_map": eng.obs_local[0].copy(),  # (N, 4+C, L, L) uint8
        "agent_class": np.eye(cfg.num_classes, dtype=np.float32)[eng.state.cls[0]],  # (N, C) one-hot
        "action_mask": eng.masks[0].astype(bool),  # (N, A)
        "active": np.ones(cfg.num_robots, dtype=bool),
    }


def log_labels(ax: Any) -> None:
    """Label a log y axis at 1-2-5 steps in short units (20k, 1.5M, 0.5)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    def short(v: float, _pos: int | None = None) -> str:
        for scale, suffix in ((1e6, "M"), (1e3, "k")):
            if v >= scale:
                return f"{v / scale:g}{suffix}"
        return f"{v:g}"

    ax.yaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
    ax.yaxis.set_major_formatter(FuncFormatter(short))
    ax.yaxis.set_minor_formatter(NullFormatter())


SCALING_AXES = (
    ("map_size", "map", "map side S (team of 3)"),
    ("team_size", "robots", "robots N (32x32 map)"),
)


def plot_scaling_panels(axes: Any, curves: dict[str, list[dict]], num_worlds: int = 64) -> None:
    """Draw ``bench_scaling`` curves on a 2x2 array of axes: engines (top) and AMAT batch-1 latency
    (bottom) against map size (left) and team size (right). Solid: wall clock; dashed: per CPU second
    of the benchmark process (steadier when other processes share the CPU)."""
    for col, (axis, key, xlabel) in enumerate(SCALING_AXES):
        rows = curves.get(axis, [])
        xs = [r[key] for r in rows]
        top, bottom = axes[0][col], axes[1][col]
        name = xlabel.split(" (")[0]
        top.set_title(f"Engines (B = {num_worlds}, 1 thread) vs {name}", fontsize=10)
        bottom.set_title(f"AMAT batch-1 decision vs {name}, all robots active", fontsize=10)
        top.set_ylabel("per second")
        bottom.set_ylabel("ms per decision (1 thread)")
        if not rows:
            for ax in (top, bottom):
                ax.text(0.5, 0.5, "scaling not measured", ha="center", va="center", transform=ax.transAxes)
                ax.set_xlabel(xlabel)
            continue
        series = (
            (
                top,
                "engine_world_ticks_per_s",
                "engine_world_ticks_per_cpu_s",
                "o",
                "BatchedWorld world-ticks/s",
            ),
            (top, "events_per_s", "events_per_cpu_s", "s", "EventEngine decision events/s"),
            (bottom, "amat_ms", "amat_cpu_ms", "o", "AMAT (torch)"),
            (bottom, "fast_amat_ms", "fast_amat_cpu_ms", "s", "FastAmat (numba)"),
        )
        for ax, wall, cpu, marker, label in series:
            pts = [(x, r[wall]) for x, r in zip(xs, rows) if r.get(wall) is not None]
            if not pts:
                continue
            (line,) = ax.plot(*zip(*pts), marker + "-", label=label)
            cpts = [(x, r[cpu]) for x, r in zip(xs, rows) if r.get(cpu) is not None]
            if cpts:
                ax.plot(*zip(*cpts), "--", color=line.get_color(), lw=1, alpha=0.7)
        bottom.axhline(1.5, color="r", ls=":", lw=1, label="1.5 ms target (N=6, S=32)")
        for ax in (top, bottom):
            ax.plot([], [], "k--", lw=1, alpha=0.7, label="dashed: by CPU time of the process")
            ax.set_yscale("log")
            log_labels(ax)
            ax.set_xscale("log", base=2)
            ax.set_xticks(xs, [str(x) for x in xs])
            ax.minorticks_off()
            ax.set_xlabel(xlabel)
            ax.grid(alpha=0.3, which="both")
            ax.legend(fontsize=7)
