"""``catmip`` command line: ``catmip train ...`` (evaluation and benchmarks come later).

Flags map onto :class:`~catmip_rl.config.TrainConfig` fields; ``--set field=value`` reaches any field
(values are JSON: ``--set env_overrides='{"comm_sigma": 4.0}'``).
"""

from __future__ import annotations

import argparse
import json
import sys

from catmip_rl.config import TRAIN_PRESETS, make_train_config

__all__ = ["main"]


def _parse_set(items: list[str]) -> dict:
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

    overrides = _parse_set(args.set)
    for name in ("iterations", "num_worlds", "epochs", "minibatches", "seed", "device", "threads",
                 "eval_every", "eval_episodes", "checkpoint_every", "lr"):  # fmt: skip
        value = getattr(args, name)
        if value is not None:
            overrides[name] = value
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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="catmip", description="CATMiP: train and evaluate AMAT")
    sub = ap.add_subparsers(dest="command", required=True)
    tr = sub.add_parser("train", help="PPO training of AMAT (SPEC §6)")
    tr.add_argument("--preset", default="paper", choices=sorted(TRAIN_PRESETS))
    tr.add_argument("--run-dir", required=True, help="where config, logs and checkpoints go")
    tr.add_argument("--resume", action="store_true", help="continue the run in --run-dir exactly")
    tr.add_argument("--iterations", type=int)
    tr.add_argument("--num-worlds", type=int)
    tr.add_argument("--epochs", type=int)
    tr.add_argument("--minibatches", type=int)
    tr.add_argument("--lr", type=float)
    tr.add_argument("--seed", type=int)
    tr.add_argument("--device", help="cpu | cuda | cuda:N")
    tr.add_argument("--threads", type=int)
    tr.add_argument("--eval-every", type=int)
    tr.add_argument("--eval-episodes", type=int)
    tr.add_argument("--checkpoint-every", type=int)
    tr.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", help="any TrainConfig field")
    tr.add_argument("--no-progress", action="store_true")
    tr.set_defaults(func=_train)
    args = ap.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
