"""``catmip`` command line: ``catmip train | eval | render | compare | bench paper | bench perf | export``.

``train`` flags map onto :class:`~catmip_rl.training.config.TrainConfig` fields; ``--set field=value``
reaches any field (values are JSON: ``--set env_overrides='{"comm_sigma": 4.0}'``). The parser is in
``parser``, the argument types in ``args``; ``train``, ``eval`` and ``render`` run here, the benchmark's
commands in ``bench_commands``.

Bad input never starts work and never shows a traceback: argparse types check every value (one line
naming the flag), each command checks its paths before running (checkpoints are read with
``weights_only=True``; outputs are never overwritten without ``--force``), and :func:`main` turns the
remaining user errors (``ValueError``, ``OSError``, ``ImportError``, ``MemoryError``) into one line on
stderr and exit code 2 (``CATMIP_DEBUG=1`` re-raises them, with the traceback); Ctrl-C is one line and
exit code 130. A training run stopped before its first checkpoint says in that line that it removed
what it wrote.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Any

from catmip_rl.cli.args import CPUS, USER_ERRORS, explain
from catmip_rl.cli.bench_commands import run_bench, run_compare, run_export, run_leaderboard
from catmip_rl.cli.parser import DEFAULT_PRESET, TRAIN_FLAGS, build_parser
from catmip_rl.cli.warmup import command_plays_amat, compile_kernels
from catmip_rl.evaluation.workers import torch_threads
from catmip_rl.training.config import TrainConfig
from catmip_rl.training.presets import FINE_TUNING_PRESETS, TRAIN_PRESETS

__all__ = ["main"]

# -- the commands ----------------------------------------------------------------------------------------


def _config(base: TrainConfig, overrides: dict[str, Any]) -> TrainConfig:
    """``base`` with ``overrides``; a ValueError naming the field for any bad value."""
    try:
        return base.replace(**overrides)
    except ValueError as err:  # the config's own checks name the field
        raise ValueError(f"bad configuration: {err}") from None
    except (TypeError, KeyError, AttributeError) as err:  # a --set value of the wrong shape
        culprit = ""
        for key, value in overrides.items():
            try:
                base.replace(**{key: value})
            except (TypeError, KeyError, AttributeError):
                culprit = f"{key} = {json.dumps(value)}: "
                break
            except ValueError:
                continue
        raise ValueError(f"bad configuration: {culprit}{type(err).__name__}: {err}") from None


def _train(args: argparse.Namespace) -> int:
    from catmip_rl.store.checkpoint import resume_checkpoint
    from catmip_rl.training.run_dir import RunDirLock
    from catmip_rl.training.train import train

    RunDirLock(args.run_dir).check_free()  # a live run's dir: say so before reading its checkpoint
    overrides = dict(args.set)
    overrides |= {name: getattr(args, name) for name in TRAIN_FLAGS if getattr(args, name) is not None}
    resumed = resume_checkpoint(args.run_dir) if args.resume else None
    if args.preset is None and resumed is not None:  # continue the run with its own config
        base = TrainConfig.from_json(resumed["config"])
    else:
        base = TRAIN_PRESETS[args.preset or DEFAULT_PRESET]
    cfg = _config(base, overrides)
    if not args.resume and args.preset in FINE_TUNING_PRESETS and not cfg.model.init_from:
        raise ValueError(
            f"preset {args.preset} fine-tunes a trained model: give --init-from MODEL (a run dir, training "
            "checkpoint or model file of the same AMAT: the memory model for general-coord)"
        )
    values = cfg.to_dict()
    for name in ("threads", "update_processes"):  # asked for here (a preset's or resumed run's value is kept)
        if name in overrides and values[name] > CPUS:
            raise ValueError(
                f"{name} = {values[name]} is more than this machine's {CPUS} CPUs; use at most {CPUS}"
            )
    done = resumed["iteration"] if resumed is not None else 0
    train(cfg, args.run_dir, resume=args.resume, progress=not args.no_progress)  # checks the run first
    if args.resume and done >= cfg.optim.iterations:
        print(
            f"{args.run_dir} is complete (iteration {done} of {cfg.optim.iterations}): nothing trained; "
            "give --iterations N (more than it has) to go on"
        )
        return 0
    print(f"run written to {args.run_dir} (config.json, metrics.csv, tensorboard/, checkpoints/)")
    return 0


def _setting(args: argparse.Namespace):
    """The flags' setting; ValueError naming ``--max-ma-ticks`` for a macro-action longer than the task's
    horizon (the flags' types check the rest)."""
    from catmip_rl.evaluation.evaluate import EvalSetting

    try:
        return EvalSetting(args.task, args.comm, args.noise, args.max_ma_ticks)
    except ValueError as err:
        if "max_ma_ticks" not in str(err):
            raise
        raise ValueError(f"--max-ma-ticks {args.max_ma_ticks}: {err}") from None


def _no_plots_note(no_plots: bool) -> str:
    """Why ``catmip eval`` draws no curve.png: '' when it draws one or ``--no-plots`` said so; else (no
    matplotlib: an env-only install, whose evaluation needs no plots) the one line that says so."""
    from catmip_rl.evaluation.plots import check_matplotlib

    if no_plots:
        return ""
    try:
        check_matplotlib()
    except ImportError as err:
        return f"catmip eval: results written, no curve.png: {err} (--no-plots skips it without this line)"
    return ""


def _eval(args: argparse.Namespace) -> int:
    from catmip_rl.evaluation.evaluate import evaluate
    from catmip_rl.evaluation.methods import PLAY_OPTIONS
    from catmip_rl.store.outputs import output_folder

    note = _no_plots_note(args.no_plots)  # decided before the work
    plots = not (args.no_plots or note)
    setting = _setting(args)
    with output_folder(args.out, "--out", force=args.force) as out:
        torch_threads(args.threads)
        result = evaluate(
            args.method,
            setting,
            args.episodes,
            args.seed,
            progress=not args.no_progress,
            allow_other_maps=args.allow_other_maps,
            threads=args.threads,
            sampled_too=not args.argmax_only,
        )
        result.write(out, curve_title=f"{args.episodes} maps (seed {args.seed})" if plots else None)
    s = result.summary
    rescue = "-" if s["mean_rescue_tick"] is None else f"{s['mean_rescue_tick']:.1f}"
    p, n = s["success_by_100"], s["episodes"]
    options = "".join(f", {name}" for key, name in PLAY_OPTIONS if s.get(key))  # how a learned policy played
    how = "" if s["actions"] == "its own" else f" ({s['actions']} actions{options})"
    print(
        f"{s['method']}{how} on {s['label']}, {n} episodes (seed {args.seed}): success "
        f"{s['success_rate']:.2f}, by tick 100 {p:.2f} (standard error {(p * (1 - p) / n) ** 0.5:.3f}), "
        f"mean rescue tick {rescue}, explored {s['mean_explored_fraction']:.2f}"
    )

    def ticks(key: str) -> str:
        return "-" if s[key] is None else f"{s[key]:.1f}"

    print(
        f"  target found at tick {ticks('mean_target_found_tick')}; a rescuer knew it "
        f"{ticks('mean_found_to_informed_ticks')} ticks later and rescued it "
        f"{ticks('mean_informed_to_rescue_ticks')} ticks after that (means over the episodes where each "
        "happened)"
    )
    if "sampled_success_rate" in s:
        print(
            f"  with sampled actions on the same maps: success {s['sampled_success_rate']:.2f}, "
            f"by tick 100 {s['sampled_success_by_100']:.2f}"
        )
    stalls = ", ".join(
        f"{k[len('stall_fraction_') :]} {v:.2f}"
        for k, v in s.items()
        if k.startswith("stall_fraction_") and v == v
    )
    print(
        f"  decisions per episode {s['decisions_per_episode']:.1f}, stalls per episode "
        f"{s['stalls_per_episode']:.1f} (stalled fraction of ended macro-actions: {stalls})"
    )
    if s["decisions"] and s["bytes_per_decision_embedding"]:
        print(
            f"messages per decision: {s['bytes_per_decision_embedding']:.0f} bytes with embeddings vs "
            f"{s['bytes_per_decision_raw']:.0f} bytes with raw macro-observations"
        )
    print(f"  maps: {s['map_set']} {s['map_set_status']} ({s['map_set_verified_episodes']} checked)")
    png = "curve.png, " if plots else ""
    print(f"wrote {out}/episodes.csv, episodes.json, curve.csv, {png}summary.json, run.json")
    if note:
        print(note, file=sys.stderr)
    return 0


def _render(args: argparse.Namespace) -> int:
    from catmip_rl.cli.render import render_episode
    from catmip_rl.store.outputs import output_file

    setting = _setting(args)
    with output_file(args.out, "--out", force=args.force, suffixes=(".gif",)):
        torch_threads(args.threads)
        path = render_episode(args.method, setting, args.out, args.episode, args.seed, args.fps)
    print(f"wrote {path}")
    return 0


COMMANDS = {
    "train": _train,
    "eval": _eval,
    "render": _render,
    "compare": run_compare,
    "bench": run_bench,
    "leaderboard": run_leaderboard,
    "export": run_export,
}


def main(argv: list[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as done:  # --help, --version, or a bad flag (argparse printed one line)
        return done.code if isinstance(done.code, int) else (0 if done.code is None else 2)
    name = f"catmip {args.name}" + (f" {args.suite}" if args.name == "bench" else "")
    previous = _stop_on_sigterm()
    try:
        if args.name in ("eval", "render", "bench", "train"):  # the first run on a machine says it compiles
            compile_kernels(amat=command_plays_amat(args))  # AMAT's kernels only where a model plays
        return COMMANDS[args.name](args)
    except BrokenPipeError:  # stdout closed by the reader (`| head`): the work and its files are done
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit
        return 0
    except (*USER_ERRORS, MemoryError) as err:
        if os.environ.get("CATMIP_DEBUG"):
            raise
        what = explain(err)
        if isinstance(err, MemoryError):
            what = f"out of memory ({what}): use a smaller map_size, num_worlds or micro_batch"
        print(f"{name}: {_one_line(what, err)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as err:
        stopped = isinstance(err, Terminated)
        print(f"{name}: {_one_line('terminated' if stopped else 'interrupted', err)}", file=sys.stderr)
        return 143 if stopped else 130
    finally:
        if previous is not None:
            import signal

            signal.signal(signal.SIGTERM, previous)


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the command is, so that it stops as Ctrl-C does: its pools and files closed
    (no half-written result, no leaked semaphore), what it finished kept."""


def _stop_on_sigterm() -> Any:
    """Turn SIGTERM into :class:`Terminated` while a command runs (main thread only); returns the
    handler it replaced (None where none was replaced)."""
    import signal
    import threading

    def stop(signum: int, _frame: Any) -> None:
        raise Terminated()

    if threading.current_thread() is not threading.main_thread():
        return None
    return signal.signal(signal.SIGTERM, stop)


def _one_line(message: str, err: BaseException) -> str:
    """``message`` and the exception's notes (what a stopped training run left behind) on one line."""
    return " ".join("; ".join([message, *getattr(err, "__notes__", ())]).split())


if __name__ == "__main__":
    sys.exit(main())
