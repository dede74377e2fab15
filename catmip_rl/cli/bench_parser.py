"""The arguments of ``catmip bench`` (suite, paper, perf), ``catmip leaderboard``, ``catmip compare`` and
``catmip export``; the parser that gathers every subcommand: :mod:`catmip_rl.cli.parser`."""

from __future__ import annotations

import argparse

from catmip_rl.cli.args import (
    CPUS,
    NON_NEGATIVE_INT,
    POSITIVE_INT,
    UP_TO_CPUS,
    add_allow_other_maps,
    add_command,
    check_methods,
    check_runs,
    checked,
    name_value,
    number_type,
    pair_list,
)

__all__ = ["add_parallel_flags", "add_suite", "add_leaderboard", "add_bench", "add_export", "add_compare"]


def add_parallel_flags(p: argparse.ArgumentParser, threads: bool = True) -> None:
    """--jobs, --threads (with ``threads``), --backend and --ray-address of a command that plays a grid of
    evaluations (bench suite, bench paper) or checks a board (leaderboard)."""
    p.add_argument(
        "--jobs",
        type=POSITIVE_INT,
        default=min(2, CPUS),
        help=f"parallel workers: processes here (at most this machine's {CPUS} CPUs), Ray tasks in flight",
    )
    if threads:
        p.add_argument(
            "--threads",
            type=UP_TO_CPUS,
            default=None,
            help="torch CPU threads of each worker (default: the CPUs each job has, at most 2)",
        )
    p.add_argument(
        "--backend",
        choices=("local", "ray"),
        default="local",
        help="where the work is played: this machine's processes, or a Ray cluster (the same files; a "
        "policy's files are shipped by content)",
    )
    p.add_argument(
        "--ray-address",
        default=None,
        metavar="ADDRESS",
        help="with --backend ray: a running cluster (auto or HOST:PORT); unset, a private one on loopback",
    )


def _add_per_method(
    p: argparse.ArgumentParser, flag: str, metavar: str, text: str, dest: str | None = None
) -> None:
    """A repeatable ``flag NAME=VALUE``: what the suite records of the method ``NAME`` (its list of
    ``(name, value)`` pairs in ``dest``)."""
    p.add_argument(
        flag,
        dest=dest,
        action="append",
        default=[],
        type=name_value,
        metavar=metavar,
        help=f"{text} (repeatable)",
    )


def add_suite(suites) -> None:
    from catmip_env.maps.map_sets import SPLITS
    from catmip_rl.benchmark.entry import EPISODES, SETTINGS, SUITE

    su = add_command(
        suites,
        "suite",
        summary=f"the benchmark suite ({SUITE}): one leaderboard entry per method",
        description=f"Play each method on the {len(SETTINGS)} settings of suite {SUITE} (Tasks 2 and 3 x "
        "communication full / sigma 4 / sigma 2 x SLAM noise 0 / 5 %) on the frozen maps of --split "
        f"(validation: seed {SPLITS['validation']}, for every choice; test: seed {SPLITS['test']}, played "
        "once per entry after every choice is frozen) and write OUT/entries/NAME.json for catmip "
        "leaderboard; per-run results in OUT/runs/. An interrupted suite continues with --resume "
        "(complete runs are read back, not played again).",
    )
    su.add_argument(
        "--method",
        action="append",
        required=True,
        type=checked(check_runs),
        help="a method (repeatable; NAME=METHOD; NAME=SPEC,SPEC,...: its training runs)",
    )
    su.add_argument(
        "--split",
        choices=sorted(SPLITS),
        default="validation",
        help="the maps: validation (tuning, gates, every choice) or test (the leaderboard's; "
        "play it once, after every choice is frozen)",
    )
    su.add_argument(
        "--episodes",
        type=number_type(int, 1, below=EPISODES + 1, bound=f"from 1 to {EPISODES}"),
        default=EPISODES,
        help="maps per setting (an entry of fewer is a preview: the leaderboard takes the suite's count)",
    )
    add_parallel_flags(su)
    _add_per_method(su, "--code", "NAME=URL", "a link to a method's code, shown on the leaderboard")
    _add_per_method(su, "--notes", "NAME=TEXT", "what a method is: its training compute and seeds")
    _add_per_method(
        su,
        "--class",
        "NAME=CLASS",
        "your py: policy's class: learned (plays from its own observations), hybrid (reads a planner at "
        "play time), planner or floor; the project's methods have theirs",
        dest="classes",
    )
    _add_per_method(
        su,
        "--chosen-on",
        "NAME=TEXT",
        "what a method's choices (hyperparameters, snapshot, variant) were made on, e.g. 'validation "
        "split'; needed on the test split",
    )
    su.add_argument("--out", default="out/suite", help="new or empty folder (or the suite to --resume)")
    su.add_argument("--resume", action="store_true", help="continue the suite in a non-empty --out")
    su.add_argument("--no-progress", action="store_true", help="no progress bar")
    su.set_defaults(name="bench")


def _replay_maps(text: str) -> int | None:
    """--replay K: a count of maps, or 'all' (None)."""
    if text == "all":
        return None
    return NON_NEGATIVE_INT(text)


def add_leaderboard(sub) -> None:
    from catmip_rl.benchmark.entry import EPISODES

    lb = add_command(
        sub,
        "leaderboard",
        summary="check suite entries and rank them (Markdown + PNG)",
        description="Check every entry (*.json) in --entries against the suite (format, every setting, the "
        "frozen maps, numbers recomputed from its rescue ticks) and write OUT/leaderboard.md and "
        "OUT/leaderboard.png; a refused entry is one line naming its file. --vs METHOD also writes "
        "OUT/vs_METHOD.md / .csv: every other entry against METHOD, setting by setting, paired on the "
        "same maps with 95 % CIs.",
    )
    lb.add_argument("--entries", default="leaderboard/entries", help="folder of entry files")
    lb.add_argument(
        "--episodes",
        type=POSITIVE_INT,
        default=EPISODES,
        help="maps per setting of every entry (the suite's; fewer: previews)",
    )
    lb.add_argument("--out", default="out/leaderboard", help="folder for leaderboard.md and leaderboard.png")
    lb.add_argument("--force", action="store_true", help="replace the files it would write in --out")
    lb.add_argument("--vs", metavar="METHOD", help="an entry's method: pair every other entry with it")
    lb.add_argument(
        "--split",
        choices=("test", "validation"),
        default="test",
        help="the split whose entries are checked: test (ranked: the leaderboard's) or validation "
        "(ordered, not ranked: for choosing)",
    )
    lb.add_argument(
        "--replay",
        type=_replay_maps,
        default=0,
        metavar="K",
        help="verify: play K maps of every setting and run of every entry again from its files, chosen "
        "at random by --seed ('all': every map), refuse an entry whose ticks differ, and play --fresh "
        "maps; writes OUT/verification.json (0: check the numbers only, the page from OUT's record)",
    )
    lb.add_argument(
        "--fresh",
        type=NON_NEGATIVE_INT,
        default=None,
        metavar="M",
        help="verify on M fresh maps a setting (a map set drawn at verification time) against each run's "
        "claim, by the fresh-map rule (docs/verification.md); default 50 with --replay, else 0",
    )
    lb.add_argument(
        "--seed",
        type=NON_NEGATIVE_INT,
        default=None,
        help="the verification's seed (the replayed maps and the fresh map set; default: drawn from the "
        "operating system now): a recorded seed repeats a check exactly",
    )
    add_parallel_flags(lb, threads=False)
    lb.add_argument("--no-progress", action="store_true", help="no progress bar")
    lb.set_defaults(name="leaderboard")


def add_bench(sub) -> None:
    from catmip_rl.benchmark.paper import DEFAULT_METHODS, FIGURES

    be = add_command(
        sub,
        "bench",
        summary="the benchmark suite, the paper's figures, or speed (benchmarks/)",
        description="catmip bench suite: the benchmark's fixed grid, one leaderboard entry "
        "per method; catmip bench paper: the paper's figures; catmip bench perf: the "
        "speed measurements of benchmarks/ (speed, not the benchmark).",
    )
    suites = be.add_subparsers(dest="suite", required=True, metavar="{suite,paper,perf}")
    add_suite(suites)
    pa = add_command(
        suites,
        "paper",
        summary="the paper's figures: success rate vs mission time",
        description="Evaluate methods on the settings of a paper figure (--figure N) or of all of them "
        "(--all) and draw success vs mission time into OUT/fig{N}/.",
    )
    pa.add_argument("--figure", type=int, choices=sorted(FIGURES), help="paper figure")
    pa.add_argument("--all", action="store_true", help="every paper figure")
    pa.add_argument(
        "--methods",
        default=",".join(DEFAULT_METHODS),
        type=checked(check_methods),
        help="comma list of methods (NAME=METHOD allowed; see catmip eval -h)",
    )
    pa.add_argument(
        "--method",
        action="append",
        default=[],
        type=checked(check_runs),
        help="one more method (repeatable); NAME=SPEC,SPEC,... the training runs of one method, "
        "summarised as their mean with a CI over runs and maps",
    )
    pa.add_argument("--episodes", type=POSITIVE_INT, default=100, help="maps per (panel, method)")
    pa.add_argument("--seed", type=NON_NEGATIVE_INT, default=0, help="map set")
    add_parallel_flags(pa)
    pa.add_argument("--out", default="out/paper", help="figures go to OUT/fig{N}/ (new or empty)")
    again = pa.add_mutually_exclusive_group()
    again.add_argument("--force", action="store_true", help="write into non-empty OUT/fig{N}/ folders")
    again.add_argument(
        "--resume",
        action="store_true",
        help="continue OUT/fig{N}/: its complete runs (same method, files, panel, seed and maps) are read "
        "back, not played again, and an interrupted figure keeps its complete runs",
    )
    pa.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_allow_other_maps(pa)
    pa.set_defaults(name="bench")
    pe = add_command(
        suites,
        "perf",
        summary="speed: the measurements of benchmarks/ (benchmarks/run_all.py)",
        description="Run benchmarks/run_all.py (from the repository root): JSON/CSV results and plots of "
        "the env, collection and training speed.",
    )
    pe.add_argument("--quick", action="store_true", help="short settings")
    pe.set_defaults(name="bench")


def add_export(sub) -> None:
    ex = add_command(
        sub,
        "export",
        summary="a training run's model as a model file",
        description="Write the model of a training run (its checkpoints/latest.pt) or of one training "
        "checkpoint as a model file (what catmip_rl/models/ ships, loadable with amat:PATH), with the run's "
        "config, iteration, training minutes and origin in the file.",
    )
    ex.add_argument("source", help="a training run dir, its checkpoints/ folder or a checkpoint file")
    ex.add_argument("--out", required=True, help="the model file to write (ending in .pt)")
    ex.add_argument("--force", action="store_true", help="overwrite an existing --out (and its .json)")
    ex.add_argument(
        "--half", action="store_true", help="float16 weights: half the bytes (a snapshot to commit)"
    )
    ex.set_defaults(name="export")


def add_compare(sub) -> None:
    co = add_command(
        sub,
        "compare",
        summary="paired differences and across-seed statistics of eval results",
        description="Compare catmip eval results: per setting each method's success by tick 100 with a 95 % "
        "CI (over the maps, or over training runs and maps); for every pair of methods on the same maps the "
        "paired difference in success by tick 100 and in mean rescue tick with 95 % CIs; across runs "
        "(training seeds) the IQM and mean with 95 % stratified-bootstrap CIs, the probability of "
        "improvement and performance profiles (rliable); curves.png overlays every method's success vs time "
        "per setting with 95 % bands. Every method must have played the same settings, seeds, horizons and "
        "maps (else one line names two folders and what differs; --unpaired shows them marked). Writes "
        "compare.md, by_setting.csv, curves.csv, paired.csv, aggregate.csv, improvement.csv and PNGs into "
        "--out (each where there is something to show).",
    )
    co.add_argument(
        "results",
        nargs="+",
        metavar="RESULT",
        help="a folder of catmip eval results (searched recursively: a bench paper figure folder works), or "
        "NAME=DIR[,DIR...]: every result under those folders as runs of the method NAME (its training seeds)",
    )
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
        "--unpaired",
        action="store_true",
        help="compare methods that did not all play the same settings, seeds, horizons and maps (refused "
        "without it): side by side, each row marked paired or unpaired, pairs only where the maps agree",
    )
    co.set_defaults(name="compare")
