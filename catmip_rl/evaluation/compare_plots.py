"""The plots of ``catmip compare``: paired differences, aggregate intervals, performance profiles."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from catmip_rl.files import atomic_savefig

__all__ = ["plot_paired", "plot_aggregate", "plot_profiles"]


def _pyplot():
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
