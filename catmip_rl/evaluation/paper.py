"""The paper's evaluation figures (Section 7, Figs. 6-11) as runnable grids of settings.

    run_figure(6, methods=["nearest", "rrt", "amat:runs/a"], episodes=100, out="out/paper")

Each figure is a row of panels (one per setting); each panel draws, for every method, the success rate
vs mission time over the same ``episodes`` maps. Every (panel, method) run is independent, so runs go
to a process pool. Written per figure under ``out/fig{N}/``: ``curves.csv`` (figure, panel, method, tick,
success_rate), ``summary.csv`` (one row per run), ``summary.md``, ``fig{N}.png``, per-run folders with
the per-episode results of :mod:`~catmip_rl.evaluation.evaluate`,
and ``marl_eval.json`` (see :func:`marl_eval_json`).

Figure layout (docs/design.md#evaluation-protocol): 6-8 = Tasks 1-3, panels = communication {full,
sigma 4, sigma 2}; 9 = SLAM noise 5 % with full communication, panels = Tasks 1-3; 10 = noise 5 % with
sigma = 2, panels = Tasks 1-3; 11 = Task 2, panels = longest macro-action 5 / 10 / 20 ticks.
"""

from __future__ import annotations

import csv
import json
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import numpy as np

from catmip_rl.checkpoint import load_model
from catmip_rl.evaluation.evaluate import EvalSetting, evaluate, progress_bar
from catmip_rl.evaluation.methods import Method, make_policy, parse_method
from catmip_rl.files import atomic_write_csv, atomic_write_text

__all__ = [
    "FIGURES", "DEFAULT_METHODS", "figure_settings", "run_figure", "marl_eval_json", "plot_figure",
    "summary_markdown",
]  # fmt: skip

DEFAULT_METHODS = ("nearest", "utility", "rrt", "apf")
SUMMARY_KEYS = (
    "episodes", "success_rate", "success_by_100", "mean_rescue_tick", "mean_target_found_tick",
    "mean_explored_fraction", "bytes_per_decision_embedding", "bytes_per_decision_raw", "seconds",
)  # fmt: skip


def _comm_panels(task: str) -> list[tuple[str, EvalSetting]]:
    return [
        ("full communication", EvalSetting(task, "full")),
        ("sigma = 4", EvalSetting(task, "4")),
        ("sigma = 2", EvalSetting(task, "2")),
    ]


def _task_panels(comm: str, noise: float) -> list[tuple[str, EvalSetting]]:
    return [(f"Task {k}", EvalSetting(f"task{k}", comm, noise)) for k in (1, 2, 3)]


FIGURES: dict[int, tuple[str, list[tuple[str, EvalSetting]]]] = {
    6: ("Task 1 (15x15, 2 robots)", _comm_panels("task1")),
    7: ("Task 2 (20x20, 3 robots)", _comm_panels("task2")),
    8: ("Task 3 (32x32, 6 robots)", _comm_panels("task3")),
    9: ("SLAM noise 5 %, full communication", _task_panels("full", 0.05)),
    10: ("SLAM noise 5 %, sigma = 2", _task_panels("2", 0.05)),
    11: (
        "Task 2, longest macro-action",
        [(f"{m} ticks", EvalSetting("task2", "full", 0.0, m)) for m in (5, 10, 20)],
    ),
}


def figure_settings(figure: int) -> list[tuple[str, EvalSetting]]:
    if figure not in FIGURES:
        raise ValueError(f"unknown figure {figure!r}; the paper's evaluation figures are {sorted(FIGURES)}")
    return FIGURES[figure][1]


def _run_one(args: tuple[Method, EvalSetting, int, int, str, int, bool]) -> dict[str, Any]:
    method, setting, episodes, seed, out, threads, allow_other_maps = args
    import torch

    torch.set_num_threads(threads)
    result = evaluate(method, setting, episodes=episodes, seed=seed, allow_other_maps=allow_other_maps)
    result.write(out)
    sampled = None if result.sampled_curve is None else result.sampled_curve.tolist()
    return {"out": out, "summary": result.summary, "curve": result.curve.tolist(), "sampled_curve": sampled}


def run_figure(
    figure: int,
    methods: list[str] | None = None,
    episodes: int = 100,
    seed: int = 0,
    out: str | Path = "out/paper",
    jobs: int = 1,
    progress: bool = True,
    allow_other_maps: bool = False,
) -> Path:
    """Run every (panel, method) of ``figure``; returns the figure's folder. Bad arguments (figure,
    methods, an unreadable AMAT checkpoint, episodes, seed, jobs) raise before any run starts."""
    _matplotlib()  # fail now rather than after the evaluations
    panels = figure_settings(figure)
    parsed: list[Method] = [parse_method(m) for m in (methods or DEFAULT_METHODS)]
    names = [m.name for m in parsed]
    if len(set(names)) != len(names):
        raise ValueError(f"method names must be unique (use NAME=METHOD), got {names}")
    for what, value, low in (("episodes", episodes, 1), ("seed", seed, 0), ("jobs", jobs, 1)):
        if not isinstance(value, int) or value < low:
            raise ValueError(f"{what} must be an int >= {low}, got {value!r}")
    for m in parsed:  # an unreadable checkpoint or a broken policy fails here, not in every run
        if m.kind == "amat":
            load_model(m.target)
        elif m.kind == "py":
            make_policy(m, panels[0][1].env_config(), seed)
    fig_dir = Path(out) / f"fig{figure}"
    grid = [(panel, setting, method) for panel, setting in panels for method in parsed]
    threads = 1 if jobs > 1 else 2
    tasks = [
        (m, st, episodes, seed, str(fig_dir / st.label / m.name), threads, allow_other_maps)
        for _, st, m in grid
    ]
    results = _map(tasks, jobs, progress, f"figure {figure}")
    curve_rows, summary_rows, runs = [], [], []
    for (panel, _setting, method), res in zip(grid, results):
        for t, v in enumerate(res["curve"]):
            curve_rows.append(
                {"figure": figure, "panel": panel, "method": method.name, "tick": t, "success_rate": v}
            )
        row = {"figure": figure, "panel": panel, "method": method.name}
        summary_rows.append(row | {k: res["summary"][k] for k in SUMMARY_KEYS})
        runs.append((panel, method.name, res["out"]))
        if res.get("sampled_curve") is not None:  # AMAT: the same maps with sampled actions
            name = f"{method.name} (sampled)"
            for t, v in enumerate(res["sampled_curve"]):
                curve_rows.append(
                    {"figure": figure, "panel": panel, "method": name, "tick": t, "success_rate": v}
                )
            s = res["summary"]
            sampled = {k: None for k in SUMMARY_KEYS} | {
                "episodes": s["episodes"],
                "success_rate": s["sampled_success_rate"],
                "success_by_100": s["sampled_success_by_100"],
                "mean_rescue_tick": s["sampled_mean_rescue_tick"],
            }
            summary_rows.append({"figure": figure, "panel": panel, "method": name} | sampled)
    fig_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_csv(fig_dir / "curves.csv", curve_rows)
    atomic_write_csv(fig_dir / "summary.csv", summary_rows)
    atomic_write_text(fig_dir / "marl_eval.json", json.dumps(marl_eval_json(runs, figure), indent=1))
    atomic_write_text(fig_dir / "summary.md", summary_markdown(summary_rows))
    plot_figure(
        fig_dir / "curves.csv", fig_dir / f"fig{figure}.png", title=f"Fig. {figure}: {FIGURES[figure][0]}"
    )
    return fig_dir


def _map(tasks: list, jobs: int, progress: bool, desc: str) -> list[dict[str, Any]]:
    bar = progress_bar(len(tasks), desc, progress, unit="run", leave=True)
    results: list[dict[str, Any]] = []
    with ExitStack() as stack:
        if jobs <= 1:
            runs = map(_run_one, tasks)
        else:
            spawn = multiprocessing.get_context("spawn")
            pool = stack.enter_context(ProcessPoolExecutor(max_workers=jobs, mp_context=spawn))
            runs = pool.map(_run_one, tasks)
        for res in runs:
            results.append(res)
            if bar is not None:
                bar.update(1)
    if bar is not None:
        bar.close()
    return results


def summary_markdown(rows: list[dict[str, Any]]) -> str:
    """Success by tick 100 / by the horizon and mean rescue tick, one row per method, one column
    group per panel."""
    panels = list(dict.fromkeys(r["panel"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    cell = {(r["panel"], r["method"]): r for r in rows}
    head = "| method | " + " | ".join(panels) + " |"
    lines = [head, "|---" * (len(panels) + 1) + "|"]
    for m in methods:
        parts = []
        for p in panels:
            r = cell.get((p, m))
            if r is None:
                parts.append("-")
                continue
            rescue = "-" if r["mean_rescue_tick"] is None else f"{r['mean_rescue_tick']:.0f}"
            parts.append(f"{r['success_by_100']:.2f} / {r['success_rate']:.2f} / {rescue}")
        lines.append(f"| {m} | " + " | ".join(parts) + " |")
    note = "\nCells: success by tick 100 / success by the horizon / mean rescue tick of rescued episodes.\n"
    return "\n".join(lines) + "\n" + note


def marl_eval_json(runs: list[tuple[str, str, str]], figure: int) -> dict[str, Any]:
    """Per-episode results in the nested layout marl-eval reads:
    ``{env: {task: {algorithm: {run: {"step_0": {metric: [per-episode values]}, "absolute_metrics":
    {...}}}}}}`` with env = ``catmip-fig{N}``, task = the panel's setting label, one run per seed."""
    data: dict[str, Any] = {}
    env = f"catmip-fig{figure}"
    for _panel, method, out in runs:
        episodes = json.loads((Path(out) / "episodes.json").read_text())
        summary = json.loads((Path(out) / "summary.json").read_text())
        horizon = summary["horizon"]
        metrics = {
            "step_count": 0,
            "success": [float(e["rescued"]) for e in episodes],
            "rescue_tick": [float(e["rescue_tick"] if e["rescued"] else horizon) for e in episodes],
            "explored_fraction": [e["explored_fraction"] for e in episodes],
        }
        absolute = {
            "success_rate": [summary["success_rate"]],
            "success_by_100": [summary["success_by_100"]],
        }
        task = summary["label"]
        run = f"seed_{summary['seed']}"
        data.setdefault(env, {}).setdefault(task, {}).setdefault(method, {})[run] = {
            "step_0": metrics,
            "absolute_metrics": absolute,
        }
    return data


def _matplotlib():
    """The matplotlib module, or an ImportError that names the extra providing it."""
    try:
        import matplotlib
    except ImportError as err:
        msg = "catmip bench paper draws figures with matplotlib: pip install 'catmip[rl]'"
        raise ImportError(msg) from err
    return matplotlib


def plot_figure(curves_csv: str | Path, png: str | Path, title: str = "") -> Path:
    """Success rate vs mission time, one panel per setting, one line per method (paper layout)."""
    matplotlib = _matplotlib()
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with open(curves_csv) as f:
        rows = list(csv.DictReader(f))
    panels = list(dict.fromkeys(r["panel"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.6), sharey=True, squeeze=False)
    colours = plt.get_cmap("tab10")
    for ax, panel in zip(axes[0], panels):
        for k, method in enumerate(methods):
            pts = [
                (int(r["tick"]), float(r["success_rate"]))
                for r in rows
                if r["panel"] == panel and r["method"] == method
            ]
            if not pts:
                continue
            t, v = np.array(pts).T
            ax.plot(t, v, color=colours(k % 10), lw=1.6, label=method)
        ax.set_title(panel)
        ax.set_xlabel("mission time (ticks)")
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("success rate")
    axes[0][-1].legend(loc="lower right", fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    png = Path(png)
    tmp = png.with_name(f".{png.stem}.tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, png)
    return png
