"""What ``catmip bench`` (suite, paper, perf), ``catmip leaderboard``, ``catmip compare`` and
``catmip export`` run (their arguments: :mod:`~catmip_rl.cli.bench_parser`)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from catmip_rl.cli.args import CPUS

__all__ = ["run_bench", "run_leaderboard", "run_compare", "run_export"]


def run_bench(args: argparse.Namespace) -> int:
    """``catmip bench``: the benchmark suite, the paper's figures or the speed measurements (benchmarks/)."""
    if args.suite == "perf":
        import subprocess

        script = Path.cwd() / "benchmarks" / "run_all.py"
        if not script.exists():
            raise FileNotFoundError(
                "catmip bench perf runs benchmarks/run_all.py: call it from the repository root"
            )
        return subprocess.call([sys.executable, str(script), *(["--quick"] if args.quick else [])])
    if args.suite == "suite":
        return _suite(args)
    from contextlib import ExitStack

    from catmip_rl.benchmark.paper import FIGURES, run_figure
    from catmip_rl.store.outputs import output_folder, remove_results

    if args.all == (args.figure is not None):
        raise ValueError("give --figure N or --all (one of them)")
    figures = sorted(FIGURES) if args.all else [args.figure]
    _check_parallel(args)
    methods = [m for m in args.methods.split(",") if m.strip()] + list(args.method)
    folders = [Path(args.out) / f"fig{fig}" for fig in figures]
    advice = "pick a new folder, pass --force to replace it, or --resume to continue it"
    with ExitStack() as held:
        for folder in folders:  # every figure's folder held and checked before the first run starts
            held.enter_context(
                output_folder(folder, "--out", force=args.force, keep=args.resume, advice=advice)
            )
        for fig, folder in zip(figures, folders):
            try:
                out = run_figure(
                    fig,
                    methods,
                    args.episodes,
                    args.seed,
                    args.out,
                    args.jobs,
                    progress=not args.no_progress,
                    allow_other_maps=args.allow_other_maps,
                    threads=args.threads,
                    resume=args.resume,
                    backend=args.backend,
                    ray_address=args.ray_address,
                )
            except BaseException:  # a figure's folder holds a whole figure or none, unless --resume
                if not args.resume:  # keeps its complete runs for the next --resume
                    remove_results(folder)
                raise
            print(f"figure {fig}: {out}/fig{fig}.png, curves.csv, summary.csv, marl_eval.json")
    return 0


def _check_parallel(args: argparse.Namespace) -> None:
    """--jobs x --threads within the machine's CPUs where the workers are this machine's processes (each
    starts that many torch threads; a private Ray cluster is on this machine too); --ray-address only
    with --backend ray."""
    here = args.backend == "local" or args.ray_address is None
    if here and args.jobs > CPUS:
        raise ValueError(f"--jobs {args.jobs}: at most {CPUS} here (this machine's CPU count)")
    threads = getattr(args, "threads", None)
    if here and threads is not None and threads * args.jobs > CPUS:
        raise ValueError(f"--jobs {args.jobs} x --threads {threads} is more than this machine's {CPUS} CPUs")
    if args.ray_address is not None and args.backend != "ray":
        raise ValueError("--ray-address is for --backend ray")


def _suite(args: argparse.Namespace) -> int:
    from catmip_rl.benchmark.entry import EPISODES, SUITE
    from catmip_rl.benchmark.suite import run_suite
    from catmip_rl.store.outputs import output_folder

    _check_parallel(args)
    advice = "pick a new folder, or --resume the suite in it"
    with output_folder(args.out, "--out", keep=args.resume, advice=advice):
        paths = run_suite(
            args.method,
            args.out,
            args.episodes,
            args.jobs,
            args.threads,
            not args.no_progress,
            dict(args.code),
            dict(args.notes),
            args.split,
            dict(args.classes),
            dict(args.chosen_on),
            args.backend,
            args.ray_address,
        )
    for path in paths:
        entry = json.loads(path.read_text())
        iqm, (low, high) = (
            entry["aggregate"]["iqm_success_by_100"],
            entry["aggregate"]["iqm_success_by_100_ci"],
        )
        print(
            f"{entry['method']}: suite {SUITE} ({entry['split']} split) IQM rescued by tick 100 "
            f"{iqm:.3f} [{low:.3f}, {high:.3f}] "
            f"over {len(entry['settings'])} settings x {entry['episodes']} maps -> {path}"
        )
    print(
        f"check and rank them: catmip leaderboard --entries {Path(args.out) / 'entries'}"
        + ("" if args.episodes == EPISODES else f" --episodes {args.episodes}")
    )
    return 0


def run_leaderboard(args: argparse.Namespace) -> int:
    """``catmip leaderboard``: the entries checked and ranked into leaderboard.md / .png (and the pairs of
    ``--vs``), the table printed."""
    from catmip_rl.benchmark.board_page import paired_names
    from catmip_rl.benchmark.fresh_rule import FRESH_MAPS
    from catmip_rl.benchmark.leaderboard import render_leaderboard
    from catmip_rl.benchmark.verify import RECORD, draw_seed
    from catmip_rl.store.outputs import check_new_file, output_folder

    _check_parallel(args)
    names = ["leaderboard.md", "leaderboard.png", *(paired_names(args.vs) if args.vs else ())]
    names += [RECORD] if args.replay != 0 or args.fresh else []
    with output_folder(args.out, "--out", keep=True):  # the README and entries beside stay
        for name in names:  # checked once held: no writer since
            check_new_file(Path(args.out) / name, "--out", force=args.force)
        fresh = args.fresh if args.fresh is not None else (FRESH_MAPS if args.replay != 0 else 0)
        verify = args.replay != 0 or fresh
        seed = args.seed if args.seed is not None or not verify else draw_seed()
        if verify:
            print(f"verification seed {seed} (repeat this check with --seed {seed})", flush=True)
        paths = render_leaderboard(
            args.entries,
            args.out,
            args.episodes,
            args.vs,
            args.split,
            args.replay,
            not args.no_progress,
            fresh,
            seed,
            args.jobs,
            backend=args.backend,
            ray_address=args.ray_address,
        )
    for path in paths:
        if path.suffix == ".md":
            print(path.read_text().split("\n\n", 2)[2].rstrip())  # the table and what it says below
    print("wrote " + ", ".join(str(p) for p in paths) + (f", {Path(args.out) / RECORD}" if verify else ""))
    for name, reason in paths.refused:
        print(f"refused: {name}: {reason}", file=sys.stderr)
    return 2 if paths.refused else 0


def run_export(args: argparse.Namespace) -> int:
    """``catmip export``: a training run's model written as a model file, with its .json beside it."""
    from catmip_rl.store.checkpoint import export_model
    from catmip_rl.store.outputs import check_new_file, output_file

    with output_file(args.out, "--out", force=args.force, suffixes=(".pt",)) as out:
        check_new_file(out.with_suffix(".json"), "--out's config file", force=args.force)  # written beside it
        path, extra = export_model(args.source, out, half=args.half)
    print(
        f"wrote {path} (+ {path.with_suffix('.json').name}): iteration {extra['iteration']}, "
        f"{extra['training_minutes']:.1f} training minutes"
    )
    return 0


def run_compare(args: argparse.Namespace) -> int:
    """``catmip compare``: result folders compared, the report written into ``--out`` and printed."""
    from catmip_rl.benchmark.compare import compare
    from catmip_rl.benchmark.results import load_results
    from catmip_rl.store.outputs import output_folder

    with output_folder(args.out, "--out", force=args.force, replace_results=False):  # it may sit beside them
        results = load_results(args.results)
        unrecorded = [str(r.path) for r in results if not r.recorded]
        if unrecorded:  # said, not hidden: their files could not be checked as one run's
            print(
                f"note: {len(unrecorded)} result folder(s) have no run.json (written by an older catmip), "
                f"so their files were not checked as one run's: {', '.join(unrecorded[:3])}"
                + (", ..." if len(unrecorded) > 3 else ""),
                file=sys.stderr,
            )
        report = compare(results, seed=args.seed, vs=args.vs, pairs=args.pairs, unpaired=args.unpaired)
        written = report.write(args.out)  # the files first: a closed pipe on stdout loses nothing
    print(report.markdown())
    print(f"wrote {args.out}/: {', '.join(p.name for p in written)}")
    return 0
