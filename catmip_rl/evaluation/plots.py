"""Every plot the evaluation commands draw: ``catmip bench paper``'s success-vs-time figure
(:func:`plot_figure`, also the demo's, ``catmip eval``'s and ``catmip compare``'s curves) and ``catmip
compare``'s paired differences, aggregate intervals and performance profiles. A setting is titled by
:func:`setting_title` ("Task 2, σ = 2, 5 % noise") wherever a figure names one."""

from __future__ import annotations

import csv
import re
from pathlib import Path
from typing import Any

import numpy as np

from catmip_rl.store.files import atomic_savefig

__all__ = [
    "setting_title",
    "check_matplotlib",
    "trailing_mean",
    "plot_figure",
    "plot_paired",
    "plot_aggregate",
    "plot_profiles",
    "method_style",
    "plot_curves",
]


LABEL = re.compile(r"(task\d+)-(full|sigma(.+))-noise(.+)-ma(\d+)")  # EvalSetting.label's form
DEFAULT_MA_TICKS = 10  # EvalSetting's longest macro-action: not said in a title


def setting_title(setting: Any) -> str:
    """The title a figure gives a setting (an ``EvalSetting`` or its label): "Task 2, σ = 2, 5 % noise",
    "Task 1, full communication", "Task 2, full communication, macro-actions ≤ 20 ticks" (SLAM noise and
    the longest macro-action are said where they are not the defaults, 0 and 10 ticks). Any other text
    (a panel already named, such as the paper figures') is returned as it is."""
    label = getattr(setting, "label", setting)
    match = LABEL.fullmatch(str(label))
    if match is None:
        return str(label)
    task, comm, sigma, noise, ma = match.groups()
    try:
        noise_pct = float(noise) * 100
    except ValueError:
        return str(label)
    parts = [f"Task {task.removeprefix('task')}", "full communication" if sigma is None else f"σ = {sigma}"]
    if noise_pct:
        parts.append(f"{noise_pct:.4g} % noise")
    if int(ma) != DEFAULT_MA_TICKS:
        parts.append(f"macro-actions ≤ {int(ma)} ticks")
    return ", ".join(parts)


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


PAIRED_KINDS = (  # colour, marker (readable in grey print too), legend text
    ("tab:green", "D", "A better: the 95 % CI lies above 0"),
    ("tab:red", "D", "B better: the 95 % CI lies below 0"),
    ("tab:gray", "o", "no difference shown: the CI holds 0"),
)


def plot_paired(rows: list[dict[str, Any]], path: Path) -> Path:
    """The paired difference in success by tick 100 (A - B, 95 % CI over maps) of each compared pair,
    grouped by setting (a heading per setting, :func:`setting_title`), with a title and a legend of what
    the colours and markers say; the figure's height sized to its rows."""
    plt = _pyplot()
    from matplotlib.lines import Line2D

    settings = list(dict.fromkeys(r["setting"] for r in rows))
    lines = len(rows) + len(settings)
    fig, ax = plt.subplots(figsize=(8, 1.9 + 0.28 * lines), layout="constrained")
    y, ticks, labels, headings = 0, [], [], []
    for setting in settings:
        ticks.append(y)
        labels.append(setting_title(setting))
        headings.append(True)
        y += 1
        for r in (r for r in rows if r["setting"] == setting):
            ci = [[r["diff"] - r["ci_low"]], [r["ci_high"] - r["diff"]]]
            kind = 0 if r["ci_low"] > 0 else 1 if r["ci_high"] < 0 else 2
            color, marker, _ = PAIRED_KINDS[kind]
            ax.errorbar(r["diff"], y, xerr=ci, fmt=marker, color=color, capsize=3)
            ticks.append(y)
            labels.append(f"{r['method_a']} − {r['method_b']}")
            headings.append(False)
            y += 1
    ax.axvline(0.0, color="k", lw=0.8)
    ax.set_yticks(ticks, labels, fontsize=8)
    for label, heading in zip(ax.get_yticklabels(), headings):
        label.set_fontweight("bold" if heading else "normal")
    ax.tick_params(axis="y", length=0)
    ax.set_ylim(y - 0.5, -0.7)
    ax.grid(axis="x", alpha=0.3)
    ax.set_xlabel("paired difference in success by tick 100, A − B (95 % CI over maps)")
    ax.set_title("Paired per-map differences in success by tick 100 (A − B)")
    handles = [Line2D([], [], color=c, marker=m, linestyle="none", label=text) for c, m, text in PAIRED_KINDS]
    fig.legend(handles=handles, loc="outside lower center", ncol=3, fontsize=8, frameon=False)
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
        profiles,
        taus,
        performance_profile_cis=cis,
        ax=ax,
        xlabel=r"success by tick 100 ($\tau$)",
        ylabel=r"fraction of (run, setting) scores $> \tau$",
    )
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


def plot_curves(
    rows: list[dict[str, Any]], png: str | Path, title: str = "", notes: dict[str, str] | None = None
) -> Path:
    """:func:`plot_figure` of rows already read: panel, method, tick, success_rate (and ci_low, ci_high,
    runs where known). Panels are titled by :func:`setting_title` (a setting's label becomes "Task 2,
    σ = 2, 5 % noise"), ``notes[panel]`` on a second line; up to three panels a row; one legend below,
    of every method that any panel draws."""
    plt = _pyplot()
    panels = list(dict.fromkeys(r["panel"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    base = [m.removesuffix(" (sampled)") for m in methods]
    index = {
        m: list(dict.fromkeys(base)).index(b) for m, b in zip(methods, base)
    }  # a sampled pass: its method's colour
    own: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in rows:
        own.setdefault((r["panel"], r["method"]), []).append(r)
    columns = len(panels) if len(panels) <= 3 else 2 if len(panels) == 4 else 3
    lines = -(-len(panels) // columns)
    legend_rows = -(-len(methods) // min(len(methods), 4))
    fig, axes = plt.subplots(
        lines,
        columns,
        figsize=(max(4.2 * columns, 6.0), 3.4 * lines + 0.5 + 0.22 * legend_rows),
        squeeze=False,
        layout="constrained",
    )
    runs = {r["method"]: int(r.get("runs") or 1) for r in rows}
    banded = any(r.get("ci_low") not in (None, "") for r in rows)
    handles: dict[str, Any] = {}
    for k, ax in enumerate(axes.flat):
        if k >= len(panels):
            ax.set_visible(False)
            continue
        panel = panels[k]
        for method in methods:
            drawn = own.get((panel, method))
            if not drawn:
                continue
            t = np.array([int(r["tick"]) for r in drawn])
            v = np.array([float(r["success_rate"]) for r in drawn])
            label = method + (f" (mean of {runs[method]} runs)" if runs[method] > 1 else "")
            style = method_style(index[method], method)
            (line,) = ax.plot(t, v, label=label, **style)
            handles.setdefault(label, line)
            if drawn[0].get("ci_low") not in (None, "") and not method.endswith("(sampled)"):
                low = np.array([float(r["ci_low"]) for r in drawn])
                high = np.array([float(r["ci_high"]) for r in drawn])
                ax.fill_between(t, low, high, color=style["color"], alpha=0.15, lw=0)
        note = (notes or {}).get(panel)
        ax.set_title(setting_title(panel) + (f"\n({note})" if note else ""), fontsize=10)
        if k + columns >= len(panels):  # the lowest panel of its column
            ax.set_xlabel("mission time (ticks)")
        if k % columns == 0:
            ax.set_ylabel("success rate (95 % band)" if banded else "success rate")
        ax.set_ylim(0, 1.02)
        ax.set_xlim(left=0)
        ax.grid(alpha=0.3)
    fig.legend(
        list(handles.values()),
        list(handles),
        loc="outside lower center",
        ncol=min(len(handles), 4),
        fontsize=8,
        frameon=False,
    )
    if title:
        fig.suptitle(title)
    return atomic_savefig(fig, png)
