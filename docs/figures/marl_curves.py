"""Learning curves of MAPPO / IPPO runs (``examples/mappo_torchrl.py``): the success rate and the
return per robot of the training episodes against training episodes, one panel row per task, a thin line
per training seed and a thick one for their mean (each a moving average over ``--smooth`` iterations).

    python docs/figures/marl_curves.py RUN_DIR ... --out docs/figures/marl_curves

Writes ``OUT.csv`` (one row per run and iteration: the raw logged values) and ``OUT.png``. Training
episodes use training activation and sampled actions, so these curves show learning, not the protocol's
numbers (those come from ``catmip eval``).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import numpy as np

from catmip_rl.evaluation.plots import trailing_mean
from catmip_rl.store.files import atomic_savefig, atomic_write_csv


def read_run(run_dir: Path) -> tuple[dict, list[dict]]:
    """(config.json, metrics.csv rows) of one run folder; SystemExit naming a folder that is not one."""
    try:
        config = json.loads((run_dir / "config.json").read_text())
        with (run_dir / "metrics.csv").open() as f:
            rows = list(csv.DictReader(f))
        config["algo"], config["task"], config["seed"]  # noqa: B018 - the keys the plot groups by
    except (OSError, ValueError, KeyError) as err:
        sys.exit(f"error: {run_dir} is not a mappo_torchrl.py run folder ({type(err).__name__}: {err})")
    return config, rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", type=Path, help="run folders of examples/mappo_torchrl.py")
    ap.add_argument("--out", type=Path, required=True, help="OUT.csv and OUT.png are written")
    ap.add_argument("--smooth", type=int, default=25, help="iterations in the moving average")
    args = ap.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = [(run, *read_run(run)) for run in args.runs]
    table = []
    for run, cfg, rows in runs:
        total = 0
        for r in rows:
            total += int(r["episodes"])
            table.append({"run": run.name, "algo": cfg["algo"], "task": cfg["task"], "seed": cfg["seed"],
                          "iteration": int(r["iteration"]), "episodes": total, "minutes": float(r["minutes"]),
                          "success_rate": float(r["success_rate"]),
                          "episode_reward": float(r["episode_reward"])})  # fmt: skip
    tasks = sorted({cfg["task"] for _, cfg, _ in runs})
    algos = sorted({cfg["algo"] for _, cfg, _ in runs})
    colours = dict(zip(algos, plt.get_cmap("tab10").colors))
    fig, axes = plt.subplots(len(tasks), 2, figsize=(10, 3.4 * len(tasks)), squeeze=False)
    for row, task in zip(axes, tasks):
        for algo in algos:
            seeds = [rows for _, cfg, rows in runs if cfg["task"] == task and cfg["algo"] == algo]
            if not seeds:
                continue
            for key, ax in (("success_rate", row[0]), ("episode_reward", row[1])):
                xs, ys = [], []
                for rows in seeds:
                    x = np.cumsum([int(r["episodes"]) for r in rows])
                    y = trailing_mean(np.array([float(r[key]) for r in rows]), args.smooth)
                    ax.plot(x, y, color=colours[algo], lw=0.6, alpha=0.45)
                    xs.append(x)
                    ys.append(y)
                n = min(len(x) for x in xs)
                label = f"{algo.upper()} (mean of {len(seeds)} seeds)"
                mean_x, mean_y = np.mean([x[:n] for x in xs], axis=0), np.mean([y[:n] for y in ys], axis=0)
                ax.plot(mean_x, mean_y, color=colours[algo], lw=2, label=label)
        row[0].set_ylabel(f"{task}: success rate")
        row[1].set_ylabel(f"{task}: return per robot")
        row[0].set_ylim(0, 1.02)
        for ax in row:
            ax.set_xlabel("training episodes")
            ax.grid(alpha=0.3)
        row[0].legend(loc="lower right", fontsize=8)
    fig.suptitle(
        f"MAPPO / IPPO training episodes (sampled actions; moving average of {args.smooth} iterations)"
    )
    fig.tight_layout()
    atomic_write_csv(args.out.with_suffix(".csv"), table)
    atomic_savefig(fig, args.out.with_suffix(".png"))
    print(f"wrote {args.out.with_suffix('.csv')} and {args.out.with_suffix('.png')}")


if __name__ == "__main__":
    main()
