"""Every plot the evaluation commands draw: ``catmip bench paper``'s success-vs-time figure
(:func:`plot_figure`, also the demo's) and ``catmip compare``'s paired differences, aggregate intervals
and performance profiles."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np

from catmip_rl.files import atomic_savefig

__all__ = [
    "check_matplotlib",
    "trailing_mean",
    "plot_figure",
    "plot_paired",
    "plot_aggregate",
    "plot_profiles",
]


def check_matplotlib() -> None:
    """Nothing if matplotlib imports; else an ImportError that names the extra providing it (a command
    calls this before its evaluations, so that it fails before the work, not after)."""
    try:
        import matplotlib  # noqa: F401
    except ImportError as err:
        raise ImportError("the plots need matplotlib: pip install 'catmip[rl]'") from err


def trailing_mean(values: np.ndarray, width: int) -> np.ndarray:
    """The moving average of a learning curve: each point the mean of itself and up to ``width - 1``
    points before it (the first points average what there is)."""
    c = np.cumsum(np.insert(np.asarray(values, float), 0, 0.0))
    end = np.arange(1, len(values) + 1)
    start = np.maximum(0, end - width)
    return (c[end] - c[start]) / (end - start)


def _pyplot():
    """matplotlib's pyplot on the Agg backend (see :func:`check_matplotlib`)."""
    check_matplotlib()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> Path:
    return atomic_savefig(fig, path)


def plot_paired(rows: list[dict[str, Any]], path: Path) -> Path:
    """One line per (setting, A vs B): the paired difference in success by tick 100 with its 95 % CI."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 1.0 + 0.32 * len(rows)), layout="constrained")
    y = np.arange(len(rows))
    diff = np.array([r["diff"] for r in rows])
    err = np.array([[r["diff"] - r["ci_low"] for r in rows], [r["ci_high"] - r["diff"] for r in rows]])
    colors = ["tab:green" if r["ci_low"] > 0 else "tab:red" if r["ci_high"] < 0 else "tab:gray" for r in rows]
    for k, color in enumerate(colors):
        ax.errorbar(diff[k], y[k], xerr=err[:, k : k + 1], fmt="o", color=color, capsize=3)
    ax.axvline(0.0, color="k", lw=0.8)
    ax.set_yticks(y, [f"{r['setting']}: {r['method_a']} − {r['method_b']}" for r in rows], fontsize=7)
    ax.invert_yaxis()
    ax.set_xlabel("paired difference in success by tick 100 (95 % CI over maps)")
    ax.set_title("green: A better, red: B better, grey: no difference shown", fontsize=9)
    return _save(fig, path)


def plot_aggregate(rows: list[dict[str, Any]], path: Path) -> Path:
    """IQM and mean of success by tick 100 per method, with 95 % stratified-bootstrap CIs."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(9, 1.2 + 0.35 * len(rows)), sharey=True, layout="constrained")
    y = np.arange(len(rows))
    for ax, key, title in zip(axes, ("iqm", "mean"), ("IQM", "mean")):  # one run: a point, no bar
        low = np.array([r[key] if r[f"{key}_ci_low"] is None else r[f"{key}_ci_low"] for r in rows])
        high = np.array([r[key] if r[f"{key}_ci_high"] is None else r[f"{key}_ci_high"] for r in rows])
        ax.barh(y, high - low, left=low, height=0.6, alpha=0.6)
        ax.scatter([r[key] for r in rows], y, color="k", marker="|", s=200, zorder=3)
        ax.set_title(f"{title} (95 % CI across runs)")
        ax.set_xlabel("success by tick 100")
        ax.set_xlim(-0.02, 1.02)  # success rates: the whole range, so no method sits on an edge
        ax.grid(axis="x", alpha=0.3)
    axes[0].set_yticks(y, [f"{r['method']} ({r['runs']} run{'s' if r['runs'] > 1 else ''})" for r in rows])
    axes[0].invert_yaxis()
    return _save(fig, path)


def plot_profiles(scores: dict[str, np.ndarray], path: Path) -> Path:
    """Performance profiles (rliable): the fraction of (run, setting) scores above each threshold."""
    from rliable import library as rly
    from rliable import plot_utils

    plt = _pyplot()
    taus = np.linspace(0.0, 1.0, 101)
    profiles, cis = rly.create_performance_profile(scores, taus, reps=2_000)
    fig, ax = plt.subplots(figsize=(7, 4.5), layout="constrained")
    plot_utils.plot_performance_profiles(
        profiles, taus, performance_profile_cis=cis, ax=ax, xlabel=r"success by tick 100 ($\tau$)",
        ylabel=r"fraction of (run, setting) scores $> \tau$",
    )  # fmt: skip
    ax.legend(loc="lower left", fontsize=8)
    return _save(fig, path)


def plot_figure(curves_csv: str | Path, png: str | Path, title: str = "") -> Path:
    """Success rate vs mission time, one panel per setting, one line per method (paper layout)."""
    plt = _pyplot()
    with open(curves_csv) as f:
        rows = list(csv.DictReader(f))
    panels = list(dict.fromkeys(r["panel"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.6), sharey=True, squeeze=False)
    colours = plt.get_cmap("tab10" if len(methods) <= 10 else "tab20")
    runs = {r["method"]: int(r.get("runs") or 1) for r in rows}
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
            label = method + (f" (mean of {runs[method]} runs)" if runs[method] > 1 else "")
            style = "--" if method.endswith("(sampled)") else "-"
            ax.plot(t, v, style, color=colours(k % colours.N), lw=1.6, label=label)
        ax.set_title(panel)
        ax.set_xlabel("mission time (ticks)")
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("success rate")
    handles, labels = axes[0][0].get_legend_handles_labels()
    columns = min(len(labels), 4)
    rows = -(-len(labels) // columns)  # below the panels, so that no curve is hidden
    fig.set_size_inches(fig.get_size_inches()[0], 3.6 + 0.22 * rows)
    fig.legend(handles, labels, loc="lower center", ncol=columns, fontsize=8, frameon=False)
    if title:
        fig.suptitle(title)
    fig.tight_layout(rect=(0, 0.22 * rows / (3.6 + 0.22 * rows) + 0.02, 1, 1))
    return atomic_savefig(fig, png)
