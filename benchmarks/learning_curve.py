"""Success rate vs wall-clock while training AMAT, against the planning baselines on the same maps.

    python benchmarks/learning_curve.py --preset task1 --minutes 40 --run-dir runs/curve-ppo
    python benchmarks/learning_curve.py --preset task1-warm --minutes 40 --run-dir runs/curve-warm
    python benchmarks/learning_curve.py --plot runs/curve-ppo runs/curve-warm --out OUT

A training run is ``catmip train`` with a wall-clock budget (``budget_minutes``: the LR decays over it)
whose periodic evaluation (argmax and sampled actions, evaluation activation (0, 0), the preset's fixed
maps) is the curve; ``--resume`` continues a run dir. ``--plot`` draws finished runs' curves against
training minutes (evaluation excluded, the imitation warm start included) with the planners on the
same maps as horizontal lines, and writes ``OUT.csv`` / ``OUT.png``. The CPU capability is recorded.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import numpy as np
import torch

from catmip_env.events import EventEngine
from catmip_env.planners import make_planner
from catmip_env.play import episode_metrics, play
from catmip_rl.cli import parse_set
from catmip_rl.files import atomic_write_csv, atomic_write_text
from catmip_rl.training.config import TrainConfig, make_train_config
from catmip_rl.training.precision import native_bf16

PLANNER_LINES = ("nearest", "rrt", "random")


def planner_success(cfg: TrainConfig, name: str) -> tuple[float, float]:
    """(rescued by the horizon, by tick 100) of a planner on the run's evaluation maps."""
    env_cfg = cfg.eval_env_config()
    eng = EventEngine(env_cfg, cfg.eval_episodes, cfg.eval_seed, goal_mode="cell")
    eng.reset()
    metrics = episode_metrics(play(eng, make_planner(name, seed=0)), env_cfg.horizon_ticks)
    return metrics["success_rate"], metrics["success_by_100"]


def curve_rows(run_dir: Path) -> list[dict]:
    """The evaluated points of a run: warm-start rounds, then PPO iterations, against minutes."""
    rows = []
    name = run_dir.name
    warm = run_dir / "warm_start.csv"
    if warm.exists():
        for r in csv.DictReader(warm.open()):
            if r.get("eval/success_rate"):
                rows.append({"run": name, "phase": "warm start", "step": int(r["round"]), **_point(r)})
    for r in csv.DictReader((run_dir / "metrics.csv").open()):
        if r.get("eval/success_rate"):
            rows.append({"run": name, "phase": "ppo", "step": int(r["iteration"]), **_point(r)})
    return rows


def _point(r: dict) -> dict:
    return {
        "minutes": float(r["time/elapsed_min"]),
        "success_rate": float(r["eval/success_rate"]),
        "success_by_100": float(r["eval/success_by_100"]),
        "sampled_success_rate": float(r["eval/sampled_success_rate"]),
        "sampled_success_by_100": float(r["eval/sampled_success_by_100"]),
    }


def plot(runs: list[Path], out: Path) -> None:
    cfg = TrainConfig.from_json((runs[0] / "config.json").read_text())
    lines = {name: planner_success(cfg, name) for name in PLANNER_LINES}
    rows = [row for run in runs for row in curve_rows(run)]
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_csv(out.with_suffix(".csv"), rows)
    meta = {"cpu_capability": torch.backends.cpu.get_cpu_capability(), "native_bf16": native_bf16(),
            "eval_episodes": cfg.eval_episodes,
            "eval_seed": cfg.eval_seed, "planners": {k: {"success_rate": v[0], "success_by_100": v[1]}
                                                       for k, v in lines.items()},
            "runs": {run.name: json.loads((run / "config.json").read_text()) for run in runs}}  # fmt: skip
    atomic_write_text(out.with_suffix(".json"), json.dumps(meta, indent=2))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2), sharex=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, key, title in ((axes[0], "success_by_100", "rescued by tick 100"),
                           (axes[1], "success_rate", "rescued by the horizon")):  # fmt: skip
        for k, run in enumerate(runs):
            pts = [r for r in rows if r["run"] == run.name]
            x = [r["minutes"] for r in pts]
            ax.plot(x, [r[key] for r in pts], "-o", ms=2.5, color=colours[k], label=f"{run.name} (argmax)")
            sampled = [r[f"sampled_{key}"] for r in pts]
            ax.plot(x, sampled, ":", color=colours[k], label=f"{run.name} (sampled)")
        for (name, vals), style in zip(lines.items(), ("--", "-.", (0, (1, 3)))):
            ax.axhline(vals[0 if key == "success_rate" else 1], color="grey", ls=style, lw=1, label=name)
        ax.set_xlabel(f"training minutes ({cfg.threads} CPU thread(s), {meta['cpu_capability']})")
        ax.set_ylabel("success rate")
        ax.set_title(f"{cfg.env_preset}, {cfg.eval_episodes} fixed maps: {title}")
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    tmp = out.with_name(out.name + ".tmp.png")
    fig.savefig(tmp, dpi=110)
    tmp.replace(out.with_suffix(".png"))
    print(f"wrote {out.with_suffix('.csv')}, {out.with_suffix('.json')} and {out.with_suffix('.png')}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--preset", default="task1", help="training preset (catmip_rl.training.config.TRAIN_PRESETS)"
    )
    ap.add_argument("--minutes", type=float, default=30.0, help="wall-clock budget of the training run")
    ap.add_argument("--threads", type=int, default=2, help="torch threads (1 to run two curves side by side)")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", help="TrainConfig override")
    ap.add_argument("--run-dir", help="the training run's directory")
    ap.add_argument("--resume", action="store_true", help="continue the run in --run-dir")
    ap.add_argument("--plot", nargs="+", type=Path, metavar="RUN_DIR", help="plot finished runs instead")
    ap.add_argument("--out", default="benchmarks/results/learning_curve", help="OUT.csv / OUT.png (--plot)")
    args = ap.parse_args()
    if args.plot:
        plot(args.plot, Path(args.out))
        return
    if not args.run_dir:
        ap.error("--run-dir is required to train (or pass --plot RUN_DIR ...)")
    from catmip_rl.training.train import train

    overrides = parse_set(args.set)
    # the budget ends the run and the LR decays over it (unless --set iterations=N runs out first)
    overrides.setdefault("iterations", 100_000)
    cfg = make_train_config(args.preset, **overrides)
    cfg = cfg.replace(budget_minutes=args.minutes, threads=args.threads)
    np.seterr(all="ignore")
    train(cfg, args.run_dir, resume=args.resume)


if __name__ == "__main__":
    main()
