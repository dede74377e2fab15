"""Every benchmark in one command, then a one-page summary against the targets.

    python benchmarks/run_all.py [--quick] [--only engine,scaling] [--out-dir benchmarks/results]

Runs ``bench_engine``, ``bench_events``, ``bench_amat``, ``bench_train``, ``bench_scaling``,
``bench_executor``, ``bench_threads`` and ``bench_peer`` (POGEMA beside the env when ``.venv-pogema`` has
it: ``make bench-peer``), each in its own process (a failure is reported and the rest
still run), each writing ``<out-dir>/<name>.json``; then writes ``<out-dir>/SUMMARY.md`` (headline
numbers against their targets, met / unmet computed from the measured values),
``<out-dir>/summary.png`` (scaling curves + every target as measured/target) and
``<out-dir>/run_all.json``. ``--quick`` passes short settings to every script (minutes instead of tens
of minutes); ``--summary-only`` rebuilds the summary from the JSON already in ``--out-dir``.
"""

from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import sys
import threading
import time
from collections import deque
from pathlib import Path

from suite import BENCHES, NAMES, Bench, RunStatus
from summary import write_summary

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


# -- running -------------------------------------------------------------------------------------------
def bench_args(bench: Bench, quick: bool, seconds: float | None, extra: dict[str, list[str]]) -> list[str]:
    args = list(bench.quick) if quick else []
    if seconds is not None and bench.takes_seconds:
        if "--seconds" in args:
            del args[args.index("--seconds") : args.index("--seconds") + 2]
        args += ["--seconds", f"{seconds:g}"]
    return args + extra.get(bench.name, [])


def _display(path: Path) -> str:
    """``path`` relative to the repository when inside it, else absolute."""
    path = path.resolve()
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def run_bench(bench: Bench, args: list[str], out_json: Path, timeout: float) -> RunStatus:
    """Run one script in a subprocess, streaming its output with a ``[name]`` prefix."""
    cmd = [sys.executable, "-u", str(HERE / bench.script), *args, "--out", str(out_json)]
    shown = ["python", os.path.relpath(cmd[2], ROOT), *cmd[3:-1], _display(out_json)]
    status = RunStatus(bench.name, ran=True, command=shlex.join(shown))
    env = os.environ | {"MPLBACKEND": "Agg", "PYTHONUNBUFFERED": "1"}
    tail: deque[str] = deque(maxlen=15)
    t0 = time.perf_counter()
    before = out_json.stat().st_mtime if out_json.exists() else None
    proc = subprocess.Popen(
        cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1
    )
    killed = threading.Event()

    def kill() -> None:
        killed.set()
        proc.kill()

    timer = threading.Timer(timeout, kill)
    timer.start()
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            line = line.rstrip("\n")
            tail.append(line)
            print(f"  [{bench.name}] {line}", flush=True)
        status.returncode = proc.wait()
    finally:
        timer.cancel()
    status.seconds = time.perf_counter() - t0
    fresh = out_json.exists() and out_json.stat().st_mtime != before
    status.ok = status.returncode == 0 and fresh
    if not status.ok:
        why = (
            f"killed after the {timeout:g} s timeout" if killed.is_set() else f"exit code {status.returncode}"
        )
        if status.returncode == 0 and not fresh:
            why = f"exited 0 but wrote no {out_json.name}"
        status.error = why + "\n" + "\n".join(tail)
    return status


def _extra_args(items: list[str]) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for item in items:
        name, sep, args = item.partition("=")
        if not sep or name not in NAMES:
            raise SystemExit(f"--pass expects NAME=ARGS with NAME in {','.join(NAMES)}, got {item!r}")
        out.setdefault(name, []).extend(shlex.split(args))
    return out


def main(argv: list[str] | None = None) -> dict[str, RunStatus]:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="short settings for every benchmark")
    ap.add_argument("--only", default=",".join(NAMES), help=f"comma-separated subset of {','.join(NAMES)}")
    ap.add_argument("--out-dir", default=str(HERE / "results"), help="where JSON, SUMMARY.md and PNGs go")
    ap.add_argument("--seconds", type=float, help="override --seconds of engine, events and scaling")
    ap.add_argument("--bf16", action="store_true", help="bench_train: also time bf16 autocast")
    ap.add_argument("--pass", dest="extra", action="append", default=[], metavar="NAME=ARGS",
                    help='extra arguments for one script, e.g. --pass "scaling=--maps 15 20"')  # fmt: skip
    ap.add_argument("--timeout", type=float, default=3600.0, help="seconds per benchmark before it is killed")
    ap.add_argument("--summary-only", action="store_true", help="only rebuild the summary from --out-dir")
    args = ap.parse_args(argv)
    only = [n.strip() for n in args.only.split(",") if n.strip()]
    unknown = sorted(set(only) - set(NAMES))
    if unknown:
        raise SystemExit(f"--only: unknown benchmark(s) {unknown}; choose from {','.join(NAMES)}")
    extra = _extra_args(args.extra)
    if args.bf16:
        extra.setdefault("train", []).append("--bf16")
    out_dir = Path(args.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    statuses: dict[str, RunStatus] = {}
    if not args.summary_only:
        todo = [b for b in BENCHES if b.name in only]
        for i, bench in enumerate(todo, 1):
            print(f"[{i}/{len(todo)}] {bench.name} ...", flush=True)
            cmd_args = bench_args(bench, args.quick, args.seconds, extra)
            try:
                st = run_bench(bench, cmd_args, out_dir / f"{bench.name}.json", args.timeout)
            except OSError as exc:
                st = RunStatus(bench.name, ran=True, error=f"could not start: {exc}")
            statuses[bench.name] = st
            verdict = "ok" if st.ok else "FAILED: " + st.error.splitlines()[0]
            print(f"[{i}/{len(todo)}] {bench.name}: {verdict} ({st.seconds:.0f} s)", flush=True)
    write_summary(out_dir, statuses, quick=args.quick)
    failed = [n for n, s in statuses.items() if not s.ok]
    if failed:
        print(f"failed: {', '.join(failed)} (see {out_dir / 'SUMMARY.md'})")
    return statuses


if __name__ == "__main__":
    sys.exit(1 if any(not s.ok for s in main().values()) else 0)
