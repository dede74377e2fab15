"""``catmip`` command line: ``catmip train | eval | render | bench paper | bench perf``.

``train`` flags map onto :class:`~catmip_rl.config.TrainConfig` fields; ``--set field=value`` reaches any
field (values are JSON: ``--set env_overrides='{"comm_sigma": 4.0}'``).
"""

from __future__ import annotations

import argparse
import json
import sys

from catmip_rl.config import TRAIN_PRESETS, make_train_config

__all__ = ["main", "parse_set"]


def parse_set(items: list[str]) -> dict:
    """``["field=value", ...]`` -> ``{field: JSON value (or the raw string)}``."""
    out = {}
    for item in items:
        if "=" not in item:
            raise SystemExit(f"--set expects field=value, got {item!r}")
        key, raw = item.split("=", 1)
        try:
            out[key] = json.loads(raw)
        except json.JSONDecodeError:
            out[key] = raw
    return out


def _train(args: argparse.Namespace) -> int:
    from catmip_rl.train import train

    overrides = parse_set(args.set)
    for name in ("iterations", "num_worlds", "epochs", "minibatches", "micro_batch", "seed", "device",
                 "threads", "update_processes", "eval_every", "eval_episodes", "checkpoint_every", "lr",
                 "collector", "ray_workers", "ray_address", "warm_start", "target_kl",
                 "precision"):  # fmt: skip
        value = getattr(args, name)
        if value is not None:
            overrides[name] = value
    if args.minutes is not None:
        overrides["budget_minutes"] = args.minutes
    try:
        cfg = make_train_config(args.preset, **overrides)
    except (TypeError, ValueError) as err:
        print(f"catmip train: bad configuration: {err}", file=sys.stderr)
        return 2
    try:
        train(cfg, args.run_dir, resume=args.resume, progress=not args.no_progress)
    except (FileExistsError, FileNotFoundError, ValueError, RuntimeError) as err:
        print(f"catmip train: {err}", file=sys.stderr)
        return 2
    print(f"run written to {args.run_dir} (config.json, metrics.csv, tensorboard/, checkpoints/)")
    return 0


def _setting(args: argparse.Namespace):
    from catmip_rl.evaluate import EvalSetting

    return EvalSetting(args.task, args.comm, args.noise, args.max_ma_ticks)


def _add_setting_flags(p: argparse.ArgumentParser) -> None:
    p.add_argument("--task", default="task1", choices=["task1", "task2", "task3"])
    p.add_argument("--comm", default="full", help="full | 4 | 2 (link range sigma in cells)")
    p.add_argument("--noise", type=float, default=0.0, help="SLAM noise: per-tick cell flip probability")
    p.add_argument("--max-ma-ticks", type=int, default=10, help="longest macro-action (5 | 10 | 20)")
    p.add_argument("--seed", type=int, default=0, help="map set: episode k plays map k of this seed")
    p.add_argument("--threads", type=int, default=2, help="torch CPU threads")


def _eval(args: argparse.Namespace) -> int:
    import torch

    from catmip_rl.evaluate import evaluate

    torch.set_num_threads(args.threads)
    try:
        setting = _setting(args)
        result = evaluate(args.method, setting, args.episodes, args.seed, progress=not args.no_progress)
    except (ValueError, FileNotFoundError) as err:
        print(f"catmip eval: {err}", file=sys.stderr)
        return 2
    out = result.write(args.out)
    s = result.summary
    rescue = "-" if s["mean_rescue_tick"] is None else f"{s['mean_rescue_tick']:.1f}"
    print(
        f"{s['method']} on {s['label']}, {s['episodes']} episodes (seed {args.seed}): success "
        f"{s['success_rate']:.2f}, by tick 100 {s['success_by_100']:.2f}, mean rescue tick {rescue}, "
        f"explored {s['mean_explored_fraction']:.2f}"
    )
    if "sampled_success_rate" in s:
        print(
            f"  with sampled actions on the same maps: success {s['sampled_success_rate']:.2f}, "
            f"by tick 100 {s['sampled_success_by_100']:.2f}"
        )
    stalls = ", ".join(f"{k[len('stall_fraction_'):]} {v:.2f}" for k, v in s.items()
                       if k.startswith("stall_fraction_") and v == v)  # fmt: skip
    print(
        f"  decisions per episode {s['decisions_per_episode']:.1f}, stalls per episode "
        f"{s['stalls_per_episode']:.1f} (stalled fraction of ended macro-actions: {stalls})"
    )
    if s["decisions"] and s["bytes_per_decision_embedding"]:
        print(
            f"messages per decision: {s['bytes_per_decision_embedding']:.0f} bytes with embeddings vs "
            f"{s['bytes_per_decision_raw']:.0f} bytes with raw macro-observations"
        )
    print(f"wrote {out}/episodes.csv, episodes.json, curve.csv, summary.json")
    return 0


def _render(args: argparse.Namespace) -> int:
    import torch

    from catmip_rl.evaluate import render_episode

    torch.set_num_threads(args.threads)
    try:
        path = render_episode(args.method, _setting(args), args.out, args.episode, args.seed, args.fps)
    except (ValueError, FileNotFoundError, ImportError) as err:
        print(f"catmip render: {err}", file=sys.stderr)
        return 2
    print(f"wrote {path}")
    return 0


def _bench(args: argparse.Namespace) -> int:
    if args.suite == "perf":
        import subprocess
        from pathlib import Path

        script = Path.cwd() / "benchmarks" / "run_all.py"
        if not script.exists():
            print(
                "catmip bench perf runs benchmarks/run_all.py: call it from the repository root",
                file=sys.stderr,
            )
            return 2
        return subprocess.call([sys.executable, str(script), *(["--quick"] if args.quick else [])])
    from catmip_rl.paper import FIGURES, run_figure

    if args.all == (args.figure is not None):
        print("catmip bench paper: give --figure N or --all", file=sys.stderr)
        return 2
    figures = sorted(FIGURES) if args.all else [args.figure]
    methods = [m for m in args.methods.split(",") if m.strip()] + list(args.method)
    try:
        for fig in figures:
            out = run_figure(fig, methods, args.episodes, args.seed, args.out, args.jobs)
            print(f"figure {fig}: {out}/fig{fig}.png, curves.csv, summary.csv, marl_eval.json")
    except (ValueError, FileNotFoundError) as err:
        print(f"catmip bench paper: {err}", file=sys.stderr)
        return 2
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="catmip", description="CATMiP: train, evaluate and benchmark AMAT")
    sub = ap.add_subparsers(dest="command", required=True)
    tr = sub.add_parser("train", help="PPO training of AMAT (SPEC §6)")
    tr.add_argument("--preset", default="paper", choices=sorted(TRAIN_PRESETS))
    tr.add_argument("--run-dir", required=True, help="where config, logs and checkpoints go")
    tr.add_argument("--resume", action="store_true", help="continue the run in --run-dir exactly")
    tr.add_argument("--iterations", type=int)
    tr.add_argument("--num-worlds", type=int)
    tr.add_argument("--epochs", type=int)
    tr.add_argument("--minibatches", type=int)
    tr.add_argument("--micro-batch", type=int, help="events per forward/backward pass (0 = whole minibatch)")
    tr.add_argument("--lr", type=float)
    tr.add_argument("--seed", type=int)
    tr.add_argument("--device", help="cpu | cuda | cuda:N")
    tr.add_argument("--threads", type=int)
    tr.add_argument(
        "--update-processes",
        type=int,
        help="CPU processes computing the update's gradients (1 thread each if > 1)",
    )
    tr.add_argument(
        "--warm-start", metavar="PLANNER",
        help="DAgger warm start from a planner's goals projected into the window: nearest, rrt, ...",
    )  # fmt: skip
    tr.add_argument("--target-kl", type=float, help="stop an iteration's PPO epochs past this approx-KL")
    tr.add_argument(
        "--precision", choices=["fp32", "bf16", "auto"], help="PPO update precision (auto: bf16 where native)"
    )
    tr.add_argument("--minutes", type=float, help="wall-clock budget: stop after it, decaying the LR over it")
    tr.add_argument("--eval-every", type=int)
    tr.add_argument("--eval-episodes", type=int)
    tr.add_argument("--checkpoint-every", type=int)
    tr.add_argument("--collector", choices=["local", "ray"], help="collect here or on Ray workers")
    tr.add_argument("--ray-workers", type=int, help="Ray workers (each collects num_worlds / N worlds)")
    tr.add_argument("--ray-address", help="Ray cluster to join: auto | HOST:PORT | ray://HOST:PORT")
    tr.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", help="any TrainConfig field")
    tr.add_argument("--no-progress", action="store_true")
    tr.set_defaults(func=_train)
    methods = (
        "nearest | utility | rrt | apf | random-frontier | random | window:PLANNER (its goals projected into "
        "the 7x7 window) | amat:PATH (model, checkpoint or run dir)"
    )
    ev = sub.add_parser("eval", help="evaluate a method on the paper's protocol (SPEC §8)")
    ev.add_argument("--method", required=True, help=methods)
    _add_setting_flags(ev)
    ev.add_argument("--episodes", type=int, default=100)
    ev.add_argument("--out", required=True, help="folder for episodes.csv/json, curve.csv, summary.json")
    ev.add_argument("--no-progress", action="store_true")
    ev.set_defaults(func=_eval)
    rd = sub.add_parser("render", help="an animated GIF of one evaluation episode")
    rd.add_argument("--method", required=True, help=methods)
    _add_setting_flags(rd)
    rd.add_argument("--episode", type=int, default=0, help="which map of the seed's map set")
    rd.add_argument("--fps", type=int, default=6)
    rd.add_argument("--out", required=True, help="GIF path")
    rd.set_defaults(func=_render)
    be = sub.add_parser("bench", help="paper figures (success vs time) or the performance benchmarks")
    be.add_argument("suite", choices=["paper", "perf"])
    be.add_argument("--figure", type=int, help="paper figure 6 | 7 | 8 | 9 | 10 | 11")
    be.add_argument("--all", action="store_true", help="every paper figure")
    be.add_argument(
        "--methods", default="nearest,utility,rrt,apf", help="comma list of methods (NAME=amat:PATH allowed)"
    )
    be.add_argument("--method", action="append", default=[], help="one more method (repeatable)")
    be.add_argument("--episodes", type=int, default=100)
    be.add_argument("--seed", type=int, default=0)
    be.add_argument("--jobs", type=int, default=2, help="parallel processes")
    be.add_argument("--out", default="out/paper")
    be.add_argument("--quick", action="store_true", help="perf: short settings")
    be.set_defaults(func=_bench)
    args = ap.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
