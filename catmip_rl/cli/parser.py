"""``catmip``'s argument parser: the subcommands, their flags and help (``main`` runs the commands).

Every numeric flag is typed (``args``), so argparse itself names a bad flag; errors are one line
(:class:`Parser`), and defaults are shown in ``--help`` (:class:`Formatter`).
"""

from __future__ import annotations

import argparse
import dataclasses
import re

from catmip_rl.cli.args import (
    CPUS,
    NON_NEGATIVE_INT,
    POSITIVE_INT,
    PROBABILITY,
    UP_TO_CPUS,
    check_comm,
    check_method,
    check_methods,
    check_runs,
    checked,
    name_value,
    number_type,
    pair_list,
    set_item,
)  # fmt: skip
from catmip_rl.training.config import TrainConfig, check_field, field_docs
from catmip_rl.training.presets import TRAIN_PRESETS

__all__ = ["DEFAULT_PRESET", "TRAIN_FLAGS", "Formatter", "Parser", "build_parser", "version"]

#: the TrainConfig fields ``catmip train`` has a flag for, and the flag; each flag's help is its field's
#: docstring and its check the field's own; every other field: ``--set FIELD=VALUE``
TRAIN_FLAGS = {
    name: {"budget_minutes": "--minutes"}.get(name, "--" + name.replace("_", "-"))
    for name in ("iterations", "num_worlds", "epochs", "minibatches", "micro_batch", "lr", "seed", "device",
                 "threads", "update_processes", "warm_start", "init_from", "target_kl", "precision",
                 "budget_minutes", "eval_every", "eval_episodes", "checkpoint_every", "collector",
                 "ray_workers", "ray_address")
}  # fmt: skip
METAVARS = {"warm_start": "PLANNER", "init_from": "MODEL", "device": "{cpu,cuda,cuda:N}",
            "precision": "{fp32,bf16,auto}", "collector": "{local,ray}",
            "ray_address": "ADDRESS", "budget_minutes": "MINUTES"}  # fmt: skip

DEFAULT_PRESET = "task1-warm"
"""``catmip train`` without ``--preset``: the Task-1 recipe (~40 minutes on one CPU thread, as the shipped
model was trained), not the paper's 62,500 iterations (days)."""


class Parser(argparse.ArgumentParser):
    """Errors as one line: ``catmip eval: error: argument --threads: expected an int >= 1, got '0'``."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")

    def parse_known_args(self, args=None, namespace=None):
        """Strict in every subcommand too: a flag that ``catmip bench perf`` does not take is refused by it,
        with its usage (argparse otherwise hands it to the top parser as an unknown argument)."""
        namespace, extras = super().parse_known_args(args, namespace)
        if extras:
            self.error(f"unrecognized arguments: {' '.join(extras)}")
        return namespace, extras


class Formatter(argparse.ArgumentDefaultsHelpFormatter):
    """Defaults shown where there is one (not for switches, nor flags that default to the preset's)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        default = action.default
        if default is None or default is False or default == [] or default is argparse.SUPPRESS:
            return action.help or ""
        return super()._get_help_string(action)


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
    tr = sub.add_parser("train", help="PPO training of AMAT", formatter_class=Formatter,
                        description="PPO training of AMAT into --run-dir (config.json, metrics.csv, "
                        "tensorboard/, checkpoints/). A new run needs a new or empty --run-dir.")  # fmt: skip
    tr.add_argument(
        "--preset", choices=sorted(TRAIN_PRESETS),
        help=f"training recipe (training.presets.TRAIN_PRESETS); default {DEFAULT_PRESET} (the Task-1 "
        "world: 12 DAgger rounds, then 2,000 PPO iterations, ~40 min on one CPU thread as the shipped model "
        "was trained; the preset itself runs 2 threads), or with --resume the run's own config. tiny: a "
        "smoke run (seconds); small: minutes; paper, paper-sync, paper-smallma: the paper's recipe (62,500 "
        "iterations: days on a CPU); "
        "paper-warm: the paper's world after a warm start; paper-sharp: a paper-warm model (--init-from) "
        "fine-tuned with a tenth of the entropy bonus",
    )  # fmt: skip
    tr.add_argument("--run-dir", required=True, help="where config.json, logs and checkpoints go")
    tr.add_argument(
        "--resume", action="store_true",
        help="continue the run in --run-dir exactly, from checkpoints/latest.pt; if that is unreadable the "
        "error names the newest readable checkpoints/iter_*.pt (copy it over latest.pt to continue from it)",
    )  # fmt: skip
    g = tr.add_argument_group(
        f"overrides of the preset (default: the preset's value; {DEFAULT_PRESET}'s shown)"
    )
    preset = TRAIN_PRESETS[DEFAULT_PRESET]
    kinds = {f.name: f.type for f in dataclasses.fields(TrainConfig)}
    for name, flag in TRAIN_FLAGS.items():
        value = getattr(preset, name)
        shown = "none" if value in (None, "") else value
        g.add_argument(
            flag, dest=name, metavar=METAVARS.get(name), type=train_value(name, kinds[name]),
            help=f"{_first_sentence(field_docs()[name])} ({DEFAULT_PRESET}: {shown})",
        )  # fmt: skip
    g.add_argument("--set", action="append", default=[], type=set_item, metavar="FIELD=VALUE",
                   help="any TrainConfig field, value as JSON (repeatable)")  # fmt: skip
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
    from catmip_rl.shipped import shipped_models

    shipped = ", ".join(shipped_models()) or "none"
    p.add_argument(
        "--method", required=True, type=checked(check_method),
        help=METHOD_HELP + f" (shipped models: {shipped})",
    )  # fmt: skip
    p.add_argument("--task", default="task1", choices=TASKS, help="evaluation task")
    p.add_argument(
        "--comm", default="full", type=checked(check_comm),
        help="full, or the link range sigma in cells (the paper's: 4, 2; any sigma >= 0.01)",
    )  # fmt: skip
    p.add_argument(
        "--noise", type=PROBABILITY, default=0.0, help="SLAM noise: per-tick cell flip probability"
    )
    p.add_argument(
        "--max-ma-ticks", type=POSITIVE_INT, default=10,
        help="longest macro-action in ticks: a positive int (the paper uses 5, 10, 20)",
    )  # fmt: skip
    p.add_argument(
        "--seed", type=NON_NEGATIVE_INT, default=0, help="map set: episode k plays map k of this seed"
    )
    p.add_argument("--threads", type=UP_TO_CPUS, default=min(2, CPUS),
                   help="CPU threads of torch and of the env (its worlds split over them)")  # fmt: skip


def add_allow_other_maps(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--allow-other-maps", action="store_true",
        help="evaluate even if this installation generates maps other than the frozen map sets' "
        "(catmip_env/frozen_maps; the summary records it); without it such a run is refused",
    )  # fmt: skip


def add_eval_render(sub) -> None:
    from catmip_env.render import RENDER_FPS

    ev = sub.add_parser(
        "eval", help="evaluate a method on the paper's protocol", formatter_class=Formatter,
        description="Evaluate a method on the paper's protocol (maps 0 .. N-1 of --seed, argmax actions for "
        "AMAT) and write episodes.csv/json, curve.csv and summary.json into --out.",
    )  # fmt: skip
    add_setting_flags(ev)
    ev.add_argument("--episodes", type=POSITIVE_INT, default=100, help="maps 0 .. N-1 of the seed")
    ev.add_argument("--out", required=True, help="new or empty folder for episodes.csv/json, curve.csv, "
                    "summary.json")  # fmt: skip
    ev.add_argument(
        "--force", action="store_true", help="write into a non-empty --out (overwriting its files)"
    )
    ev.add_argument("--no-progress", action="store_true", help="no progress bar")
    ev.add_argument(
        "--no-plots", action="store_true",
        help="write no curve.png (the results only). Without matplotlib (an env-only install) the results "
        "are written all the same and one line says that the plots need the render extra",
    )  # fmt: skip
    ev.add_argument(
        "--argmax-only", action="store_true",
        help="play a learned policy's argmax actions only, not the maps again with sampled actions (half the "
        "time; the summary then has no sampled_* numbers)",
    )  # fmt: skip
    add_allow_other_maps(ev)
    ev.set_defaults(name="eval")
    rd = sub.add_parser(
        "render", help="an animated GIF of one evaluation episode", formatter_class=Formatter,
        description="Play one evaluation episode (map --episode of --seed) with a method and write it as an "
        "animated GIF (one frame per tick).",
    )  # fmt: skip
    add_setting_flags(rd)
    rd.add_argument("--episode", type=NON_NEGATIVE_INT, default=0, help="which map of the seed's map set")
    rd.add_argument("--fps", type=POSITIVE_INT, default=RENDER_FPS,
                    help="frames (ticks) per second (the env's metadata render_fps)")  # fmt: skip
    rd.add_argument("--out", required=True, help="path of the GIF to write (ending in .gif)")
    rd.add_argument("--force", action="store_true", help="overwrite an existing --out")
    rd.set_defaults(name="render")


def add_parallel_flags(p: argparse.ArgumentParser) -> None:
    """--jobs and --threads of a command that plays a grid of evaluations (bench suite, bench paper)."""
    p.add_argument("--jobs", type=UP_TO_CPUS, default=min(2, CPUS), help="parallel processes")
    p.add_argument("--threads", type=UP_TO_CPUS, default=None,
                   help="torch CPU threads of each process (default: 2 with one job, else 1)")  # fmt: skip


def add_suite(suites) -> None:
    from catmip_rl.evaluation.suite import EPISODES, SETTINGS, SPLITS, SUITE

    su = suites.add_parser(
        "suite", help=f"the benchmark suite ({SUITE}): one leaderboard entry per method",
        formatter_class=Formatter,
        description=f"Play each method on the {len(SETTINGS)} settings of suite {SUITE} (Tasks 2 and 3 x "
        "communication full / sigma 4 / sigma 2 x SLAM noise 0 / 5 %) on the frozen maps of --split "
        f"(validation: seed {SPLITS['validation']}, for every choice; test: seed {SPLITS['test']}, played "
        "once per entry after every choice is frozen) and write OUT/entries/NAME.json for catmip "
        "leaderboard; per-run results in OUT/runs/. An interrupted suite continues with --resume "
        "(complete runs are read back, not played again).",
    )  # fmt: skip
    su.add_argument(
        "--method", action="append", required=True, type=checked(check_runs),
        help="a method (repeatable; NAME=METHOD; NAME=SPEC,SPEC,...: its training runs)",
    )  # fmt: skip
    su.add_argument("--split", choices=sorted(SPLITS), default="validation",
                    help="the maps: validation (tuning, gates, every choice) or test (the leaderboard's; "
                    "play it once, after every choice is frozen)")  # fmt: skip
    su.add_argument("--episodes", type=number_type(int, 1, below=EPISODES + 1, bound=f"from 1 to {EPISODES}"),
                    default=EPISODES, help="maps per setting (an entry of fewer is a preview: the "
                    "leaderboard takes the suite's count)")  # fmt: skip
    add_parallel_flags(su)
    su.add_argument("--code", action="append", default=[], type=name_value, metavar="NAME=URL",
                    help="a link to a method's code, shown on the leaderboard (repeatable)")  # fmt: skip
    su.add_argument("--notes", action="append", default=[], type=name_value, metavar="NAME=TEXT",
                    help="what a method is: its training compute and seeds (repeatable)")  # fmt: skip
    su.add_argument("--class", dest="classes", action="append", default=[], type=name_value,
                    metavar="NAME=CLASS", help="your py: policy's class: learned (plays from its own "
                    "observations), hybrid (reads a planner at play time), planner or floor; the "
                    "project's methods have theirs (repeatable)")  # fmt: skip
    su.add_argument("--chosen-on", action="append", default=[], type=name_value, metavar="NAME=TEXT",
                    help="what a method's choices (hyperparameters, snapshot, variant) were made on, e.g. "
                    "'validation split'; needed on the test split (repeatable)")  # fmt: skip
    su.add_argument("--out", default="out/suite", help="new or empty folder (or the suite to --resume)")
    su.add_argument("--resume", action="store_true", help="continue the suite in a non-empty --out")
    su.add_argument("--no-progress", action="store_true", help="no progress bar")
    su.set_defaults(name="bench")


def add_leaderboard(sub) -> None:
    from catmip_rl.evaluation.suite import EPISODES

    lb = sub.add_parser(
        "leaderboard", help="check suite entries and rank them (Markdown + PNG)", formatter_class=Formatter,
        description="Check every entry (*.json) in --entries against the suite (format, every setting, the "
        "frozen maps, numbers recomputed from its rescue ticks) and write OUT/leaderboard.md and "
        "OUT/leaderboard.png; a refused entry is one line naming its file. --vs METHOD also writes "
        "OUT/vs_METHOD.md / .csv: every other entry against METHOD, setting by setting, paired on the "
        "same maps with 95 % CIs.",
    )  # fmt: skip
    lb.add_argument("--entries", default="leaderboard/entries", help="folder of entry files")
    lb.add_argument("--episodes", type=POSITIVE_INT, default=EPISODES,
                    help="maps per setting of every entry (the suite's; fewer: previews)")  # fmt: skip
    lb.add_argument("--out", default="out/leaderboard", help="folder for leaderboard.md and leaderboard.png")
    lb.add_argument("--force", action="store_true", help="replace the files it would write in --out")
    lb.add_argument("--vs", metavar="METHOD", help="an entry's method: pair every other entry with it")
    lb.add_argument("--split", choices=("test", "validation"), default="test",
                    help="the split whose entries are ranked (the leaderboard's: test)")  # fmt: skip
    lb.add_argument("--replay", type=NON_NEGATIVE_INT, default=0, metavar="K",
                    help="play the first K maps of every setting and run of every entry again from its "
                    "files and refuse an entry whose ticks differ (0: check the numbers only)")  # fmt: skip
    lb.add_argument("--no-progress", action="store_true", help="no progress bar")
    lb.set_defaults(name="leaderboard")


def add_bench(sub) -> None:
    from catmip_rl.evaluation.paper import DEFAULT_METHODS, FIGURES

    be = sub.add_parser("bench", help="the benchmark suite, the paper's figures or the speed benchmarks",
                        description="catmip bench suite: the benchmark's fixed grid, one leaderboard entry "
                        "per method; catmip bench paper: the paper's figures; catmip bench perf: the "
                        "performance benchmarks of benchmarks/.")  # fmt: skip
    suites = be.add_subparsers(dest="suite", required=True, metavar="{suite,paper,perf}")
    add_suite(suites)
    pa = suites.add_parser(
        "paper", help="the paper's figures: success rate vs mission time", formatter_class=Formatter,
        description="Evaluate methods on the settings of a paper figure (--figure N) or of all of them "
        "(--all) and draw success vs mission time into OUT/fig{N}/.",
    )  # fmt: skip
    pa.add_argument("--figure", type=int, choices=sorted(FIGURES), help="paper figure")
    pa.add_argument("--all", action="store_true", help="every paper figure")
    pa.add_argument("--methods", default=",".join(DEFAULT_METHODS), type=checked(check_methods),
                    help="comma list of methods (NAME=METHOD allowed; see catmip eval -h)")  # fmt: skip
    pa.add_argument("--method", action="append", default=[], type=checked(check_runs),
                    help="one more method (repeatable); NAME=SPEC,SPEC,... the training runs of one method, "
                         "summarised as their mean with a CI over runs and maps")  # fmt: skip
    pa.add_argument("--episodes", type=POSITIVE_INT, default=100, help="maps per (panel, method)")
    pa.add_argument("--seed", type=NON_NEGATIVE_INT, default=0, help="map set")
    add_parallel_flags(pa)
    pa.add_argument("--out", default="out/paper", help="figures go to OUT/fig{N}/ (new or empty)")
    again = pa.add_mutually_exclusive_group()
    again.add_argument("--force", action="store_true", help="write into non-empty OUT/fig{N}/ folders")
    again.add_argument(
        "--resume", action="store_true",
        help="continue OUT/fig{N}/: its complete runs (same method, files, panel, seed and maps) are read "
        "back, not played again, and an interrupted figure keeps its complete runs",
    )  # fmt: skip
    pa.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_allow_other_maps(pa)
    pa.set_defaults(name="bench")
    pe = suites.add_parser(
        "perf", help="the performance benchmarks (benchmarks/run_all.py)", formatter_class=Formatter,
        description="Run benchmarks/run_all.py (from the repository root): JSON/CSV results and plots of "
        "the env, collection and training speed.",
    )  # fmt: skip
    pe.add_argument("--quick", action="store_true", help="short settings")
    pe.set_defaults(name="bench")


def add_export(sub) -> None:
    ex = sub.add_parser(
        "export", help="a training run's model as a model file", formatter_class=Formatter,
        description="Write the model of a training run (its checkpoints/latest.pt) or of one training "
        "checkpoint as a model file (what catmip_rl/models/ ships, loadable with amat:PATH), with the run's "
        "config, iteration, training minutes and origin in the file.",
    )  # fmt: skip
    ex.add_argument("source", help="a training run dir, its checkpoints/ folder or a checkpoint file")
    ex.add_argument("--out", required=True, help="the model file to write (ending in .pt)")
    ex.add_argument("--force", action="store_true", help="overwrite an existing --out (and its .json)")
    ex.add_argument(
        "--half", action="store_true", help="float16 weights: half the bytes (a snapshot to commit)"
    )
    ex.set_defaults(name="export")


def add_compare(sub) -> None:
    co = sub.add_parser(
        "compare", help="paired differences and across-seed statistics of eval results",
        formatter_class=Formatter,
        description="Compare catmip eval results: per setting each method's success by tick 100 with a 95 % "
        "CI (over the maps, or over training runs and maps); for every pair of methods on the same maps the "
        "paired difference in success by tick 100 and in mean rescue tick with 95 % CIs; across runs "
        "(training seeds) the IQM and mean with 95 % stratified-bootstrap CIs, the probability of "
        "improvement and performance profiles (rliable); curves.png overlays every method's success vs time "
        "per setting with 95 % bands. Every method must have played the same settings, seeds, horizons and "
        "maps (else one line names two folders and what differs; --unpaired shows them marked). Writes "
        "compare.md, by_setting.csv, curves.csv, paired.csv, aggregate.csv, improvement.csv and PNGs into "
        "--out (each where there is something to show).",
    )  # fmt: skip
    co.add_argument(
        "results", nargs="+", metavar="RESULT",
        help="a folder of catmip eval results (searched recursively: a bench paper figure folder works), or "
        "NAME=DIR[,DIR...]: every result under those folders as runs of the method NAME (its training seeds)",
    )  # fmt: skip
    co.add_argument("--out", default="out/compare", help="new or empty folder for the tables and plots")
    co.add_argument("--force", action="store_true", help="write into a non-empty --out")
    co.add_argument("--seed", type=NON_NEGATIVE_INT, default=0, help="seed of the bootstrap resampling")
    pick = co.add_mutually_exclusive_group()
    pick.add_argument("--vs", metavar="METHOD", help="pair every method with this one only (METHOD - it)")
    pick.add_argument(
        "--pairs",
        type=pair_list,
        action="extend",
        metavar="A:B,...",
        help="only these pairs (A - B); repeat the flag or separate pairs by commas",
    )
    co.add_argument(
        "--unpaired", action="store_true",
        help="compare methods that did not all play the same settings, seeds, horizons and maps (refused "
        "without it): side by side, each row marked paired or unpaired, pairs only where the maps agree",
    )  # fmt: skip
    co.set_defaults(name="compare")


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
