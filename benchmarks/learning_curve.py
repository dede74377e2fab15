"""Success rate vs wall-clock while training AMAT on Task 1, against the planning baselines.

    python benchmarks/learning_curve.py [--minutes 30] [--out benchmarks/results/learning_curve]

Trains with the ``small`` preset's PPO settings on the Task-1 world (15x15, rescuer + explorer,
activation (2, 5) in training) and, every ``--eval-every`` iterations, evaluates the deterministic policy
on a fixed set of Task-1 maps (evaluation activation (0, 0), horizon 300). The Nearest planner and the
random floors on the same maps are drawn as horizontal lines. Writes ``.csv`` and ``.png``.
"""

from __future__ import annotations

import argparse
import csv
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from catmip_env.baselines import make_planner
from catmip_env.events import EventEngine, random_valid_actions
from catmip_rl.amat import AMAT
from catmip_rl.collect import Collector
from catmip_rl.config import make_train_config
from catmip_rl.gae import async_gae  # noqa: F401  (compiled before the clock starts)
from catmip_rl.ppo import ValueNorm
from catmip_rl.train import build_batch, make_optimizer, ppo_update

EVAL_EPISODES = 64
EVAL_SEED = 2025


def planner_success(cfg_env, name: str) -> tuple[float, float]:
    eng = EventEngine(cfg_env, EVAL_EPISODES, EVAL_SEED, goal_mode="cell")
    planner = make_planner(name, seed=0)
    eng.reset()
    while not eng.state.done.all():
        eng.step(planner.act(eng))
    t = eng.state.rescue_tick
    return float((t >= 0).mean()), float(((t >= 0) & (t <= 100)).mean())


def random_window_success(cfg_env) -> tuple[float, float]:
    eng = EventEngine(cfg_env, EVAL_EPISODES, EVAL_SEED)
    rng = np.random.default_rng(0)
    eng.reset()
    while not eng.state.done.all():
        eng.step(random_valid_actions(eng.masks, rng))
    t = eng.state.rescue_tick
    return float((t >= 0).mean()), float(((t >= 0) & (t <= 100)).mean())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--eval-every", type=int, default=10)
    ap.add_argument("--out", default="benchmarks/results/learning_curve")
    args = ap.parse_args()
    cfg = make_train_config(
        "small", env_preset="task1", env_overrides={"activation": [2, 5]}, iterations=10_000, eval_every=0
    )
    eval_env = cfg.env_config().replace(activation=(0, 0))
    lines = {
        "nearest": planner_success(eval_env, "nearest"),
        "random-frontier": planner_success(eval_env, "random-frontier"),
        "random window (+rescue rule)": planner_success(eval_env, "random"),
        "uniform random window": random_window_success(eval_env),
    }
    torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)
    model = AMAT(cfg.amat_config())
    opt = make_optimizer(model, cfg)
    value_norm = ValueNorm()
    collector = Collector(cfg.env_config(), cfg.num_worlds, cfg.seed, cfg.gamma)
    evaluator = Collector(eval_env, EVAL_EPISODES, EVAL_SEED, cfg.gamma)
    rows = []
    t0 = time.perf_counter()
    it, episodes = 0, 0
    while True:
        if it % args.eval_every == 0:
            r = evaluator.collect(model, 0, deterministic=True)
            t = evaluator.engine.state.rescue_tick
            rows.append({"iteration": it, "episodes": episodes, "minutes": (time.perf_counter() - t0) / 60,
                         "success_rate": r.stats["success_rate"],
                         "success_by_100": float(((t >= 0) & (t <= 100)).mean())})  # fmt: skip
            print(rows[-1], flush=True)
        if time.perf_counter() - t0 > args.minutes * 60:
            break
        rollout = collector.collect(model, episodes, gen)
        episodes += cfg.num_worlds
        batch, _ = build_batch(
            rollout, value_norm, cfg.gamma, cfg.lam, cfg.env_config().num_classes, torch.device("cpu")
        )
        ppo_update(model, opt, batch, cfg, gen)
        it += 1
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp())
    with (tmp / "curve.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
        for name, (succ, by100) in lines.items():
            f.write(f"# {name}: success_rate {succ:.3f}, success_by_100 {by100:.3f}\n")
    shutil.move(tmp / "curve.csv", out.with_suffix(".csv"))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharex=True)
    minutes = [r["minutes"] for r in rows]
    for ax, key, title in (
        (axes[0], "success_rate", "rescued by tick 300"),
        (axes[1], "success_by_100", "rescued by tick 100"),
    ):
        ax.plot(minutes, [r[key] for r in rows], "k-o", ms=3, label="AMAT (training)")
        for (name, vals), colour in zip(lines.items(), ("tab:blue", "tab:green", "tab:orange", "tab:red")):
            ax.axhline(vals[0 if key == "success_rate" else 1], color=colour, ls="--", lw=1, label=name)
        ax.set_xlabel("wall-clock minutes (2 CPU threads)")
        ax.set_ylabel("success rate")
        ax.set_title(f"Task 1, {EVAL_EPISODES} fixed maps: {title}")
        ax.set_ylim(0, 1.02)
    axes[0].legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(out.with_suffix(".png"), dpi=110)
    print(f"wrote {out.with_suffix('.csv')} and {out.with_suffix('.png')}")


if __name__ == "__main__":
    main()
