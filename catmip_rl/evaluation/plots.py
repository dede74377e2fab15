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
    "method_style",
    "plot_curves",
]


def check_matplotlib() -> None:
    """Nothing if matplotlib imports; else an ImportError that names the extra providing it (a command
    calls this before its evaluations, so that it fails before the work, not after)."""
    try:
        import matplotlib  # noqa: F401
    except ImportError as err:
        raise ImportError(
            "the plots need the render extra (matplotlib): pip install 'catmip[render]'"
        ) from err


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
    """The paired difference in success by tick 100 (A - B, 95 % CI) of each compared pair, grouped by
    setting (a heading per setting), the figure's height sized to its rows."""
    plt = _pyplot()
    settings = list(dict.fromkeys(r["setting"] for r in rows))
    lines = len(rows) + len(settings)
    fig, ax = plt.subplots(figsize=(8, 0.9 + 0.28 * lines), layout="constrained")
    y, ticks, labels = 0, [], []
    for setting in settings:
        ax.text(0.0, y, setting, transform=ax.get_yaxis_transform(), ha="right", va="center",
                fontsize=8, fontweight="bold")  # fmt: skip
        y += 1
        for r in (r for r in rows if r["setting"] == setting):
            ci = [[r["diff"] - r["ci_low"]], [r["ci_high"] - r["diff"]]]
            color = "tab:green" if r["ci_low"] > 0 else "tab:red" if r["ci_high"] < 0 else "tab:gray"
            marker = "o" if color == "tab:gray" else "D"  # readable in grey print too
            ax.errorbar(r["diff"], y, xerr=ci, fmt=marker, color=color, capsize=3)
            ticks.append(y)
            labels.append(f"{r['method_a']} − {r['method_b']}")
            y += 1
    ax.axvline(0.0, color="k", lw=0.8)
    ax.set_yticks(ticks, labels, fontsize=7)
    ax.set_ylim(y - 0.5, -0.7)
    ax.grid(axis="x", alpha=0.3)
    ax.set_xlabel("paired difference in success by tick 100, A − B (95 % CI over maps)")
    ax.set_title(
        "diamonds: a difference shown (green: A better, red: B better); circles: none shown", fontsize=9
    )
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


LINESTYLES = ("-", "--", "-.", (0, (6, 1.5, 1, 1.5, 1, 1.5)))  # ":" is kept for sampled passes


def method_style(k: int, method: str) -> dict[str, Any]:
    """Colour and line style of the ``k``-th method of a figure: ten colours, and a dash pattern that
    changes with each colour so that neighbours differ in grey print too; a method's sampled pass
    (``NAME (sampled)``) is drawn thin and dotted."""
    import matplotlib

    colour = matplotlib.colormaps["tab10"](k % 10)
    if method.endswith("(sampled)"):
        return {"color": colour, "linestyle": ":", "lw": 1.1}
    return {"color": colour, "linestyle": LINESTYLES[(k + k // 10) % len(LINESTYLES)], "lw": 1.7}


def plot_figure(curves_csv: str | Path, png: str | Path, title: str = "") -> Path:
    """Success rate vs mission time, one panel per setting, one line per method (paper layout), with the
    95 % band over maps (and runs) where ``curves.csv`` has ``ci_low`` / ``ci_high``."""
    with open(curves_csv) as f:
        rows = list(csv.DictReader(f))
    return plot_curves(rows, png, title)


def plot_curves(rows: list[dict[str, Any]], png: str | Path, title: str = "") -> Path:
    """:func:`plot_figure` of rows already read: panel, method, tick, success_rate (and ci_low, ci_high,
    runs where known)."""
    plt = _pyplot()
    panels = list(dict.fromkeys(r["panel"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    base = [m.removesuffix(" (sampled)") for m in methods]
    index = {
        m: list(dict.fromkeys(base)).index(b) for m, b in zip(methods, base)
    }  # a sampled pass: its method's colour
    fig, axes = plt.subplots(
        1, len(panels), figsize=(max(4.2 * len(panels), 6.0), 3.6), sharey=True, squeeze=False
    )
    runs = {r["method"]: int(r.get("runs") or 1) for r in rows}
    for ax, panel in zip(axes[0], panels):
        for method in methods:
            own = [r for r in rows if r["panel"] == panel and r["method"] == method]
            if not own:
                continue
            t = np.array([int(r["tick"]) for r in own])
            v = np.array([float(r["success_rate"]) for r in own])
            label = method + (f" (mean of {runs[method]} runs)" if runs[method] > 1 else "")
            style = method_style(index[method], method)
            ax.plot(t, v, label=label, **style)
            if own[0].get("ci_low") not in (None, "") and not method.endswith("(sampled)"):
                low = np.array([float(r["ci_low"]) for r in own])
                high = np.array([float(r["ci_high"]) for r in own])
                ax.fill_between(t, low, high, color=style["color"], alpha=0.15, lw=0)
        ax.set_title(panel)
        ax.set_xlabel("mission time (ticks)")
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
    banded = any(r.get("ci_low") not in (None, "") for r in rows)
    axes[0][0].set_ylabel("success rate (95 % band)" if banded else "success rate")
    handles, labels = axes[0][0].get_legend_handles_labels()
    columns = min(len(labels), 4)
    rows = -(-len(labels) // columns)  # below the panels, so that no curve is hidden
    fig.set_size_inches(fig.get_size_inches()[0], 3.6 + 0.22 * rows)
    fig.legend(handles, labels, loc="lower center", ncol=columns, fontsize=8, frameon=False)
    if title:
        fig.suptitle(title)
    fig.tight_layout(rect=(0, 0.22 * rows / (3.6 + 0.22 * rows) + 0.02, 1, 1))
    return atomic_savefig(fig, png)
