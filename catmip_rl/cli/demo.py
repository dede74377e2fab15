"""The README's main job: train AMAT briefly on Task 1, then evaluate it against the planners.

    python -m catmip_rl.cli.demo [--iterations 60] [--episodes 64] [--out out/demo]

1. ``catmip train --preset task1-warm`` shortened: its 12 DAgger rounds against the window-projected
   Nearest planner, then ``--iterations`` PPO iterations (a few minutes on 2 cores) into ``OUT/train``
   (config, metrics.csv, warm_start.csv, TensorBoard, checkpoints);
2. the evaluation protocol (docs/design.md#evaluation-protocol) on ``--episodes`` fixed Task-1 maps:
   the model just trained, the shipped model (``catmip_rl/models/amat_task1.pt``, the same recipe
   trained longer), the planning baselines and the imitation teacher (``window:nearest``), all on the
   same maps;
3. ``OUT/results.csv`` + ``results.md`` (table), ``OUT/success.png`` (success rate vs mission time),
   ``OUT/episode.gif`` (the shipped model on episode 0), per-method folders with per-episode results.
"""

from __future__ import annotations

import argparse
import os
import re
import time
from pathlib import Path

import torch

from catmip_rl.cli.render import render_episode
from catmip_rl.cli.warmup import compile_kernels
from catmip_rl.evaluation.evaluate import EvalSetting, evaluate
from catmip_rl.evaluation.plots import plot_figure
from catmip_rl.store.files import atomic_write_csv, atomic_write_text
from catmip_rl.store.shipped import resolve_model

PLANNERS = ("nearest", "utility", "rrt", "apf", "random-frontier", "random-rescue", "random-uniform")
COLUMNS = (
    "success_rate",
    "success_by_100",
    "sampled_success_by_100",
    "mean_rescue_tick",
    "mean_target_found_tick",
    "mean_explored_fraction",
    "stalls_per_episode",
    "bytes_per_decision_embedding",
    "seconds",
)


def _fmt(v) -> str:
    if v is None:
        return "-"
    return f"{v:.2f}" if isinstance(v, float) else str(v)


def main(argv: list[str] | None = None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--iterations", type=int, default=60, help="PPO iterations after the warm start")
    ap.add_argument("--episodes", type=int, default=64, help="evaluation maps (Task 1)")
    ap.add_argument("--seed", type=int, default=0, help="evaluation map set")
    ap.add_argument(
        "--threads", type=int, default=min(2, os.cpu_count() or 1), help="torch threads (at most the CPUs)"
    )
    ap.add_argument("--planners", default=",".join(PLANNERS), help="comma-separated planners to compare")
    ap.add_argument("--warm-start-rounds", type=int, default=None, help="DAgger rounds (task1-warm's: 12)")
    ap.add_argument("--worlds", type=int, default=None, help="episodes per PPO iteration and DAgger round")
    ap.add_argument("--out", default="out/demo")
    args = ap.parse_args(argv)
    out = Path(args.out)
    torch.set_num_threads(args.threads)
    shipped = resolve_model("task1")  # the README's row: a missing file is an error, never a dropped row
    compile_kernels()  # the first run on a machine: say so and how long it takes

    # 1. a short training run (a fresh one every time: the folder is replaced)
    from catmip_rl.training.presets import make_train_config
    from catmip_rl.training.train import train

    run_dir = out / "train"
    if run_dir.exists():  # a new run needs a new or empty run dir
        import shutil

        shutil.rmtree(run_dir)
    # the warm start of task1-warm with 256 episodes a DAgger round (not 64) and the teacher's "stay" labels
    # unscored: the short run's imitation then generalises instead of fitting its buffer
    # (docs/notes/training-experiments.md)
    cfg = make_train_config(
        "task1-warm",
        iterations=args.iterations,
        threads=args.threads,
        eval_every=0,
        checkpoint_every=args.iterations,
        warm_start_worlds=args.worlds or 256,
        warm_start_stay=False,
    )
    if args.warm_start_rounds is not None:
        cfg = cfg.replace(warm_start_rounds=args.warm_start_rounds)
    if args.worlds is not None:
        cfg = cfg.replace(num_worlds=args.worlds)
    print(
        f"[1/3] training AMAT on Task 1: {cfg.imitation.warm_start_rounds} imitation rounds, then "
        f"{args.iterations} PPO iterations x {cfg.collection.num_worlds} episodes, {run_dir}"
    )
    t0 = time.perf_counter()
    train(cfg, run_dir, progress=True)
    print(f"      {time.perf_counter() - t0:.0f} s")

    # 2. evaluation on the same maps
    setting = EvalSetting("task1")
    methods = [f"AMAT (demo, {args.iterations} it)=amat:{run_dir}", f"AMAT (shipped)=amat:{shipped}"]
    methods += [*args.planners.split(","), "window:nearest"]
    print(f"[2/3] evaluating {len(methods)} methods on {args.episodes} Task-1 maps (seed {args.seed})")
    rows, curves = [], []
    for spec in methods:
        res = evaluate(spec, setting, episodes=args.episodes, seed=args.seed, progress=True)
        res.write(out / "eval" / re.sub(r"[^A-Za-z0-9_.-]+", "_", res.method).strip("_"))
        rows.append({"method": res.method} | {k: res.summary.get(k) for k in COLUMNS})
        curves += [
            {
                "figure": "demo",
                "panel": "Task 1, full communication",
                "method": res.method,
                "tick": t,
                "success_rate": float(v),
            }
            for t, v in enumerate(res.curve)
        ]

    # 3. table, plot, GIF
    atomic_write_csv(out / "results.csv", rows)
    atomic_write_csv(out / "curves.csv", curves)
    lines = ["| method | " + " | ".join(COLUMNS) + " |", "|---" * (len(COLUMNS) + 1) + "|"]
    lines += ["| " + " | ".join([r["method"], *(_fmt(r[k]) for k in COLUMNS)]) + " |" for r in rows]
    atomic_write_text(out / "results.md", "\n".join(lines) + "\n")
    png = plot_figure(out / "curves.csv", out / "success.png", title=f"Task 1, {args.episodes} maps")
    print("[3/3] rendering an episode of the shipped model")
    gif = render_episode(f"amat:{shipped}", setting, out / "episode.gif", episode=0, seed=args.seed)

    print(f"\n{args.episodes} Task-1 maps, same maps for every method:")
    print(
        f"{'method':>28} {'success':>8} {'by t=100':>9} {'sampled':>8} {'rescue t':>9} {'found t':>8} "
        f"{'explored':>9} {'stalls':>7}"
    )
    for r in rows:
        print(
            f"{r['method']:>28} {r['success_rate']:>8.2f} {r['success_by_100']:>9.2f} "
            f"{_fmt(r['sampled_success_by_100']):>8} {_fmt(r['mean_rescue_tick']):>9} "
            f"{_fmt(r['mean_target_found_tick']):>8} {r['mean_explored_fraction']:>9.2f} "
            f"{r['stalls_per_episode']:>7.1f}"
        )
    print("(by t=100: argmax, the paper's protocol; sampled: AMAT with sampled actions, rescued by t=100)")
    print(f"\nwrote {out / 'results.md'}, {out / 'results.csv'}, {png}, {gif}, {run_dir} and {out / 'eval'}/")
    return rows


if __name__ == "__main__":
    main()
