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

import json
from pathlib import Path
from typing import Any

import numpy as np

from catmip_rl.benchmark.jobs import Job, check_methods, default_threads, map_jobs, run_dir
from catmip_rl.evaluation.evaluate import EvalSetting
from catmip_rl.evaluation.methods import Method, parse_runs
from catmip_rl.evaluation.plots import check_matplotlib, plot_figure
from catmip_rl.evaluation.stats import curve_band, success_interval
from catmip_rl.store.files import atomic_write_csv, atomic_write_text

__all__ = [
    "FIGURES",
    "DEFAULT_METHODS",
    "figure_settings",
    "run_figure",
    "marl_eval_json",
    "summary_markdown",
    "summary_table",
    "summary_cell",
]

DEFAULT_METHODS = ("nearest", "utility", "rrt", "apf")
SUMMARY_KEYS = (
    "episodes",
    "success_rate",
    "success_by_100",
    "mean_rescue_tick",
    "mean_target_found_tick",
    "mean_explored_fraction",
    "bytes_per_decision_embedding",
    "bytes_per_decision_raw",
    "seconds",
)
SAMPLED_KEYS = ("success_rate", "success_by_100", "mean_rescue_tick")  # what the sampled pass reports


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


def run_figure(
    figure: int,
    methods: list[str] | None = None,
    episodes: int = 100,
    seed: int = 0,
    out: str | Path = "out/paper",
    jobs: int = 1,
    progress: bool = True,
    allow_other_maps: bool = False,
    threads: int | None = None,
    resume: bool = False,
    backend: str = "local",
    ray_address: str | None = None,
) -> Path:
    """Run every (panel, method) of ``figure``; returns the figure's folder. A method given as
    ``NAME=SPEC,SPEC,...`` has several training runs (:func:`parse_runs`): each plays the same maps (in
    ``LABEL/NAME/runK/``) and the figure shows their mean, with a 95 % CI over runs and maps. A ``py:``
    policy that cannot play a panel's world (``WorldNotSupported``) is left out of that panel: a method
    plays each panel with those of its runs that can, and one none of whose runs can is listed as not
    played in ``summary.md``. Bad arguments (figure, methods, an unreadable AMAT checkpoint, a broken
    policy, episodes, seed, jobs, threads) raise before any run starts. ``threads``: torch threads of each
    job (default 2 for one job, else 1). ``resume``: a run whose folder already holds its complete results
    is read back, not played again (:attr:`~catmip_rl.benchmark.jobs.Job.resume`)."""
    check_matplotlib()  # fail now rather than after the evaluations
    panels = figure_settings(figure)
    groups: list[list[Method]] = [parse_runs(m) for m in (methods or DEFAULT_METHODS)]
    names = [runs[0].name for runs in groups]
    if len(set(names)) != len(names):
        raise ValueError(f"method names must be unique (use NAME=METHOD), got {names}")
    threads = default_threads(jobs, threads)
    for what, value, low in (
        ("episodes", episodes, 1),
        ("seed", seed, 0),
        ("jobs", jobs, 1),
        ("threads", threads, 1),
    ):
        if not isinstance(value, int) or value < low:
            raise ValueError(f"{what} must be an int >= {low}, got {value!r}")
    plays, not_played = check_methods(groups, panels, seed)  # a broken checkpoint or policy fails here
    fig_dir = Path(out) / f"fig{figure}"
    tasks = [
        Job(
            m,
            st,
            episodes,
            seed,
            str(run_dir(fig_dir / st.label / m.name, k, len(runs))),
            threads,
            allow_other_maps,
            resume=resume,
        )
        for panel, st in panels
        for name in names
        for runs in [plays.get((panel, name), [])]
        for k, m in enumerate(runs)
    ]
    results = iter(map_jobs(tasks, jobs, progress, f"figure {figure}", backend, ray_address))
    curve_rows, summary_rows, runs_written = [], [], []
    for panel, _setting in panels:
        for name in names:
            if (panel, name) not in plays:
                continue
            res = [next(results) for _ in plays[(panel, name)]]
            runs_written += [(panel, name, r["out"], k) for k, r in enumerate(res)]
            for label, curve_key, tick_key, prefix in (
                (name, "curve", "rescue_tick", ""),  # the paper's protocol: argmax for AMAT
                (f"{name} (sampled)", "sampled_curve", "sampled_rescue_tick", "sampled_"),  # AMAT's sampled
            ):
                if res[0][curve_key] is None:
                    continue
                at = {"figure": figure, "panel": panel, "method": label}
                curve = np.mean([r[curve_key] for r in res], axis=0)
                horizon = int(res[0]["summary"]["horizon"])
                low, high = curve_band(np.array([r["ticks"][tick_key] for r in res], float), horizon)
                for t, v in enumerate(curve):
                    band = {"ci_low": low[t], "ci_high": high[t]}
                    curve_rows.append(at | {"tick": t, "success_rate": v, **band, "runs": len(res)})
                summary_rows.append(at | _summary(res, tick_key, prefix))
    fig_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_csv(fig_dir / "curves.csv", curve_rows)
    atomic_write_csv(fig_dir / "summary.csv", summary_rows)
    atomic_write_text(fig_dir / "marl_eval.json", json.dumps(marl_eval_json(runs_written, figure), indent=1))
    atomic_write_text(fig_dir / "summary.md", summary_markdown(summary_rows, not_played))
    plot_figure(
        fig_dir / "curves.csv", fig_dir / f"fig{figure}.png", title=f"Fig. {figure}: {FIGURES[figure][0]}"
    )
    return fig_dir


def _summary(res: list[dict[str, Any]], tick_key: str, prefix: str) -> dict[str, Any]:
    """The summary row of one method's runs in one panel: each summary key the mean over the runs (a
    key the runs lack, e.g. the sampled pass's bytes, is None), the number of runs, and the 95 % CI of
    success by tick 100 over the maps (one run) or over runs and maps (several)."""
    horizon = int(res[0]["summary"]["horizon"])
    ticks = np.array([r["ticks"][tick_key] for r in res], float)  # (runs, maps), nan: not rescued
    with np.errstate(invalid="ignore"):
        success = ticks <= min(100, horizon)
    low, high, over = success_interval(success)
    row: dict[str, Any] = {}
    for key in SUMMARY_KEYS:
        values = [r["summary"].get(prefix + key if key in SAMPLED_KEYS else key) for r in res]
        if key == "episodes":
            row[key] = values[0]
        elif (prefix and key not in SAMPLED_KEYS) or any(v is None for v in values):
            row[key] = None
        else:
            row[key] = float(np.mean(values))
    return row | {
        "runs": len(res),
        "success_by_100_ci_low": low,
        "success_by_100_ci_high": high,
        "ci_over": over,
    }


def _number(value: Any) -> float | None:
    """A summary value as a float, None where there is none (None, or "" / "None" read back from CSV)."""
    return None if value in (None, "", "None") else float(value)


def summary_cell(row: dict[str, Any]) -> str:
    """One run's or method's cell: success by tick 100 [95 % CI] / success by the horizon / mean rescue
    tick of the rescued episodes (a row read back from ``summary.csv`` works too; the CI is left out
    where the row has none)."""
    low, high = _number(row.get("success_by_100_ci_low")), _number(row.get("success_by_100_ci_high"))
    ci = "" if low is None or high is None else f" [{low:.2f}, {high:.2f}]"
    tick = _number(row["mean_rescue_tick"])
    rescue = "–" if tick is None else f"{tick:.0f}"
    return f"{_number(row['success_by_100']):.2f}{ci} / {_number(row['success_rate']):.2f} / {rescue}"


def summary_table(rows: list[dict[str, Any]], bold: bool = False) -> str:
    """The markdown table of a figure's summary rows: a row per method, a column per panel, each cell a
    :func:`summary_cell`; with ``bold`` the best success by tick 100 of each column is bold."""
    panels = list(dict.fromkeys(r["panel"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    at = {(r["method"], r["panel"]): r for r in rows}
    best = {p: max(_number(r["success_by_100"]) for r in rows if r["panel"] == p) for p in panels}
    lines = ["| method | " + " | ".join(panels) + " |", "|---" * (len(panels) + 1) + "|"]
    for m in methods:
        cells = []
        for p in panels:
            r = at.get((m, p))
            text = "—" if r is None else summary_cell(r)
            if r is not None and bold and _number(r["success_by_100"]) == best[p]:
                text = f"**{text}**"
            cells.append(text)
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def summary_markdown(rows: list[dict[str, Any]], not_played: dict[tuple[str, str], str] | None = None) -> str:
    """:func:`summary_table` and what its cells say, with the (panel, method) pairs left out and why."""
    note = (
        "\nCells: success by tick 100 [95 % CI over the maps, or over training runs and maps for a method "
        "with several] / success by the horizon / mean rescue tick of rescued episodes. A method with "
        "several training runs shows their mean; — : not played (below).\n"
    )
    left_out = "".join(f"\n* {m} on {p}: not played ({why})" for (p, m), why in (not_played or {}).items())
    return summary_table(rows) + "\n" + note + left_out + ("\n" if left_out else "")


def marl_eval_json(runs: list[tuple[str, str, str, int]], figure: int) -> dict[str, Any]:
    """Per-episode results in the nested layout marl-eval reads:
    ``{env: {task: {algorithm: {run: {"step_0": {metric: [per-episode values]}, "absolute_metrics":
    {...}}}}}}`` with env = ``catmip-fig{N}``, task = the panel's setting label and run = ``seed_K``, the
    K-th training run of the method (``seed_0`` for a method with one); ``runs``: (panel, method, result
    folder, K)."""
    data: dict[str, Any] = {}
    env = f"catmip-fig{figure}"
    for _panel, method, out, k in runs:
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
        data.setdefault(env, {}).setdefault(task, {}).setdefault(method, {})[f"seed_{k}"] = {
            "step_0": metrics,
            "absolute_metrics": absolute,
        }
    return data
