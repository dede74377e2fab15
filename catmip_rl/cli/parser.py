"""``catmip``'s argument parser: the subcommands, their flags and help (``main`` runs the commands).

Every numeric flag is typed (``args``), so argparse itself names a bad flag; errors are one line
(:class:`Parser`), and defaults are shown in ``--help`` (:class:`Formatter`).
"""

from __future__ import annotations

import argparse
import re

from catmip_rl.cli.args import (
    CPUS,
    NON_NEGATIVE_INT,
    POSITIVE_INT,
    PROBABILITY,
    UP_TO_CPUS,
    Parser,
    add_allow_other_maps,
    add_command,
    check_comm,
    check_method,
    checked,
    set_item,
)
from catmip_rl.cli.bench_parser import add_bench, add_compare, add_export, add_leaderboard
from catmip_rl.training.config import check_field, field_docs, field_types
from catmip_rl.training.presets import TRAIN_PRESETS

__all__ = ["DEFAULT_PRESET", "TRAIN_FLAGS", "build_parser", "version"]

#: the TrainConfig fields ``catmip train`` has a flag for, and the flag; each flag's help is its field's
#: docstring and its check the field's own; every other field: ``--set FIELD=VALUE``
TRAIN_FLAGS = {
    name: {"budget_minutes": "--minutes"}.get(name, "--" + name.replace("_", "-"))
    for name in (
        "iterations",
        "num_worlds",
        "epochs",
        "minibatches",
        "micro_batch",
        "lr",
        "seed",
        "device",
        "threads",
        "update_processes",
        "warm_start",
        "init_from",
        "target_kl",
        "precision",
        "budget_minutes",
        "eval_every",
        "eval_episodes",
        "checkpoint_every",
        "collector",
        "ray_workers",
        "ray_address",
    )
}
METAVARS = {
    "warm_start": "PLANNER",
    "init_from": "MODEL",
    "device": "{cpu,cuda,cuda:N}",
    "precision": "{fp32,bf16,auto}",
    "collector": "{local,ray}",
    "ray_address": "ADDRESS",
    "budget_minutes": "MINUTES",
}

DEFAULT_PRESET = "task1-warm"
"""``catmip train`` without ``--preset``: the Task-1 recipe (~40 minutes on one CPU thread, as the shipped
model was trained), not the paper's 62,500 iterations (days)."""


def version() -> str:
    import catmip_rl

    version = getattr(catmip_rl, "__version__", None)
    if version is None:
        from importlib.metadata import PackageNotFoundError
        from importlib.metadata import version as dist_version

        try:
            version = dist_version("catmip")
        except PackageNotFoundError:
            version = "unknown"
    return version


def add_train(sub) -> None:
    tr = add_command(
        sub,
        "train",
        summary="PPO training of AMAT",
        description="PPO training of AMAT into --run-dir (config.json, metrics.csv, "
        "tensorboard/, checkpoints/). A new run needs a new or empty --run-dir.",
    )
    tr.add_argument(
        "--preset",
        choices=sorted(TRAIN_PRESETS),
        help=f"training recipe (training.presets.TRAIN_PRESETS); default {DEFAULT_PRESET} (the Task-1 "
        "world: 12 DAgger rounds, then 2,000 PPO iterations, ~40 min on one CPU thread as the shipped model "
        "was trained; the preset itself runs 2 threads), or with --resume the run's own config. tiny: a "
        "smoke run (seconds); small: minutes; paper, paper-sync, paper-smallma: the paper's recipe (62,500 "
        "iterations: days on a CPU); "
        "paper-warm: the paper's world after a warm start; general: amat_general.pt's first stage; "
        "general-rrt, -relay, -relay-noise, -coord: its later stages, each --init-from the one before",
    )
    tr.add_argument("--run-dir", required=True, help="where config.json, logs and checkpoints go")
    tr.add_argument(
        "--resume",
        action="store_true",
        help="continue the run in --run-dir exactly, from checkpoints/latest.pt; if that is unreadable the "
        "error names the newest readable checkpoints/iter_*.pt (copy it over latest.pt to continue from it)",
    )
    g = tr.add_argument_group(
        f"overrides of the preset (default: the preset's value; {DEFAULT_PRESET}'s shown)"
    )
    preset = TRAIN_PRESETS[DEFAULT_PRESET].to_dict()
    kinds = field_types()
    for name, flag in TRAIN_FLAGS.items():
        value = preset[name]
        shown = "none" if value in (None, "") else value
        g.add_argument(
            flag,
            dest=name,
            metavar=METAVARS.get(name),
            type=train_value(name, kinds[name]),
            help=f"{_first_sentence(field_docs()[name])} ({DEFAULT_PRESET}: {shown})",
        )
    g.add_argument(
        "--set",
        action="append",
        default=[],
        type=set_item,
        metavar="FIELD=VALUE",
        help="any TrainConfig field, value as JSON (repeatable)",
    )
    tr.add_argument("--no-progress", action="store_true", help="no progress bar")
    tr.set_defaults(name="train")


def _first_sentence(doc: str) -> str:
    """A field docstring's first sentence, without reST markup, as a flag's help (% escaped for argparse)."""
    text = doc.replace("``", "").replace("%", "%%")
    end = re.search(r"\.(\s|$)", text)
    return text[: end.start()] if end else text


def train_value(name: str, kind: str):
    """The argparse type of the flag of TrainConfig field ``name`` (annotated ``kind``): the text as the
    field's type, checked by the field's own check (``training.config.check_field``); threads and
    processes also at most this machine's CPU count."""
    convert = {"int": int, "float": float}.get(kind, str)

    def parse(text: str):
        try:
            value = convert(text)
        except ValueError:
            noun = "an int" if convert is int else "a number"
            raise argparse.ArgumentTypeError(f"expected {noun}, got {text!r}") from None
        if name in ("threads", "update_processes"):
            value = UP_TO_CPUS(text)
        try:
            check_field(name, value)
        except ValueError as err:
            raise argparse.ArgumentTypeError(str(err)) from None
        return value

    parse.__name__ = f"TrainConfig.{name}"
    return parse


def add_setting_flags(p: argparse.ArgumentParser) -> None:
    from catmip_rl.evaluation.evaluate import TASKS
    from catmip_rl.evaluation.methods import METHOD_HELP
    from catmip_rl.store.shipped import shipped_models

    shipped = ", ".join(shipped_models()) or "none"
    p.add_argument(
        "--method",
        required=True,
        type=checked(check_method),
        help=METHOD_HELP + f" (shipped models: {shipped})",
    )
    p.add_argument("--task", default="task1", choices=TASKS, help="evaluation task")
    p.add_argument(
        "--comm",
        default="full",
        type=checked(check_comm),
        help="full, or the link range sigma in cells (the paper's: 4, 2; any sigma >= 0.01)",
    )
    p.add_argument(
        "--noise", type=PROBABILITY, default=0.0, help="SLAM noise: per-tick cell flip probability"
    )
    p.add_argument(
        "--max-ma-ticks",
        type=POSITIVE_INT,
        default=10,
        help="longest macro-action in ticks: a positive int (the paper uses 5, 10, 20)",
    )
    p.add_argument(
        "--seed", type=NON_NEGATIVE_INT, default=0, help="map set: episode k plays map k of this seed"
    )
    p.add_argument(
        "--threads",
        type=UP_TO_CPUS,
        default=min(2, CPUS),
        help="CPU threads of torch and of the env (its worlds split over them)",
    )


def add_eval_render(sub) -> None:
    from catmip_env.envs.render import RENDER_FPS

    ev = add_command(
        sub,
        "eval",
        summary="evaluate a method on the paper's protocol",
        description="Evaluate a method on the paper's protocol (maps 0 .. N-1 of --seed, argmax actions for "
        "AMAT) and write episodes.csv/json, curve.csv and summary.json into --out.",
    )
    add_setting_flags(ev)
    ev.add_argument("--episodes", type=POSITIVE_INT, default=100, help="maps 0 .. N-1 of the seed")
    ev.add_argument(
        "--out", required=True, help="new or empty folder for episodes.csv/json, curve.csv, summary.json"
    )
    ev.add_argument(
        "--force", action="store_true", help="write into a non-empty --out (overwriting its files)"
    )
    ev.add_argument("--no-progress", action="store_true", help="no progress bar")
    ev.add_argument(
        "--no-plots",
        action="store_true",
        help="write no curve.png (the results only). Without matplotlib (an env-only install) the results "
        "are written all the same and one line says that the plots need the render extra",
    )
    ev.add_argument(
        "--argmax-only",
        action="store_true",
        help="play a learned policy's argmax actions only, not the maps again with sampled actions (half the "
        "time; the summary then has no sampled_* numbers)",
    )
    add_allow_other_maps(ev)
    ev.set_defaults(name="eval")
    rd = add_command(
        sub,
        "render",
        summary="an animated GIF of one evaluation episode",
        description="Play one evaluation episode (map --episode of --seed) with a method and write it as an "
        "animated GIF (one frame per tick).",
    )
    add_setting_flags(rd)
    rd.add_argument("--episode", type=NON_NEGATIVE_INT, default=0, help="which map of the seed's map set")
    rd.add_argument(
        "--fps",
        type=POSITIVE_INT,
        default=RENDER_FPS,
        help="frames (ticks) per second (the env's metadata render_fps)",
    )
    rd.add_argument("--out", required=True, help="path of the GIF to write (ending in .gif)")
    rd.add_argument("--force", action="store_true", help="overwrite an existing --out")
    rd.set_defaults(name="render")


def build_parser() -> argparse.ArgumentParser:
    ap = Parser(
        prog="catmip",
        description="CATMiP: train, evaluate and benchmark AMAT",
        epilog="Bad input exits with code 2 and one line on stderr, before any work starts; "
        "CATMIP_DEBUG=1 shows the traceback instead.",
    )
    ap.add_argument("--version", action="version", version=f"catmip {version()}")
    sub = ap.add_subparsers(
        dest="command", required=True, metavar="{train,eval,render,compare,bench,leaderboard,export}"
    )
    add_train(sub)
    add_eval_render(sub)
    add_compare(sub)
    add_bench(sub)
    add_leaderboard(sub)
    add_export(sub)
    return ap
