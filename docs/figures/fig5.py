"""The paper's Fig. 5 from training runs: success and return against training episodes, one line per
variant (AMAT, Synch-AMAT, SmallMA).

    python docs/figures/fig5.py AMAT=run-records/paper-warm Synch-AMAT=runs/sync SmallMA=runs/smallma \
        --out docs/figures/fig5

(the paper runs' ``metrics.csv`` are in git history, run-records/README.md says where; the figure's
points are ``docs/figures/fig5.csv``)

Three panels, each a moving average over ``--smooth`` logged points: the periodic evaluation (rescued by
tick 100 with argmax actions on the run's fixed evaluation maps of its training world, evaluation
activation (0, 0)); the success of the training episodes themselves (sampled actions, training
activation); their mean return per robot (rescuers' and explorers'). The imitation warm start's rounds
are the first points of each line. Writes ``OUT.csv`` (the raw points) and ``OUT.png``.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

from catmip_rl.evaluation.plots import trailing_mean
from catmip_rl.store.files import atomic_savefig, atomic_write_csv

PANELS = (
    ("eval_success", "evaluation: rescued by tick 100 (argmax)"),
    ("train_success", "training episodes: rescued (sampled)"),
    ("train_return", "training episodes: return per robot"),
)


def _float(v: str | None) -> float:
    return float(v) if v not in (None, "") else np.nan


def read_points(name: str, run: Path) -> list[dict]:
    """One row per logged point of a run: episodes so far and the three panels' values (NaN: not logged)."""
    points = []
    try:
        warm = run / "warm_start.csv"
        if warm.exists():
            with warm.open() as f:
                for r in csv.DictReader(f):
                    points.append({"method": name, "phase": "warm start", "episodes": int(r["episodes"]),
                                   "eval_success": _float(r.get("eval/success_by_100")),
                                   "train_success": _float(r.get("rollout/success_rate")),
                                   "train_return": np.nan})  # fmt: skip
        with (run / "metrics.csv").open() as f:
            for r in csv.DictReader(f):
                ret = np.array([_float(r.get(f"rollout/return_{c}")) for c in ("rescuer", "explorer")])
                mean_return = np.nan if np.all(np.isnan(ret)) else float(np.nanmean(ret))
                points.append({"method": name, "phase": "ppo", "episodes": int(r["episodes"]),
                               "eval_success": _float(r.get("eval/success_by_100")),
                               "train_success": _float(r.get("rollout/success_rate")),
                               "train_return": mean_return})  # fmt: skip
    except (OSError, KeyError, ValueError) as err:
        sys.exit(f"error: {run} is not a catmip train run folder ({type(err).__name__}: {err})")
    return points


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", help="NAME=RUN_DIR of catmip train runs")
    ap.add_argument("--out", type=Path, required=True, help="OUT.csv and OUT.png are written")
    ap.add_argument("--smooth", type=int, default=20, help="logged points in the moving average")
    args = ap.parse_args()
    named = []
    for spec in args.runs:
        name, sep, path = spec.partition("=")
        if not sep or not name:
            sys.exit(f"error: expected NAME=RUN_DIR, got {spec!r}")
        named.append((name, Path(path)))
    points = [p for name, run in named for p in read_points(name, run)]
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(PANELS), figsize=(4.4 * len(PANELS), 3.6))
    for k, (name, _) in enumerate(named):
        rows = [p for p in points if p["method"] == name]
        x = np.array([p["episodes"] for p in rows], float)
        for ax, (key, title) in zip(axes, PANELS):
            y = np.array([p[key] for p in rows], float)
            keep = ~np.isnan(y)  # the points with a value
            sx, sy = x[keep], trailing_mean(y[keep], args.smooth)
            ax.plot(sx, sy, color=plt.get_cmap("tab10")(k), lw=1.6, label=name)
            ax.set_title(title, fontsize=10)
    for ax in axes:
        ax.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v / 1000:.0f}k"))
        ax.set_xlabel("training episodes")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("success rate")
    axes[0].legend(fontsize=8, loc="lower right")
    fig.suptitle(f"Fig. 5: training the three variants (moving average of {args.smooth} points)")
    fig.tight_layout()
    atomic_write_csv(args.out.with_suffix(".csv"), points)
    atomic_savefig(fig, args.out.with_suffix(".png"))
    print(f"wrote {args.out.with_suffix('.csv')} and {args.out.with_suffix('.png')}")


if __name__ == "__main__":
    main()
