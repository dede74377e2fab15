"""Every benchmark in one command, then a one-page summary against the targets.

    python benchmarks/run_all.py [--quick] [--only engine,scaling] [--out-dir benchmarks/results]

Runs ``bench_engine``, ``bench_events``, ``bench_amat``, ``bench_train`` and ``bench_scaling``, each in its
own process (a failure is reported and the rest still run), each writing ``<out-dir>/<name>.json``; then
writes ``<out-dir>/SUMMARY.md`` (headline numbers against their targets, met / unmet computed from the
measured values), ``<out-dir>/summary.png`` (scaling curves + every target as measured/target) and
``<out-dir>/run_all.json``. ``--quick`` passes short settings to every script (minutes instead of
tens of minutes); ``--summary-only`` rebuilds the summary from the JSON already in ``--out-dir``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shlex
import subprocess
import sys
import threading
import time
from collections import deque
from dataclasses import asdict, dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

from common import plot_scaling_panels, write_json

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


@dataclass(frozen=True)
class Bench:
    """One benchmark script and the arguments ``--quick`` gives it."""

    name: str
    script: str
    quick: tuple[str, ...]
    takes_seconds: bool  # accepts --seconds (overridden by run_all's --seconds)


BENCHES = (
    Bench("engine", "bench_engine.py", ("--seconds", "1", "--batches", "1", "64"), True),
    Bench("events", "bench_events.py", ("--seconds", "1", "--decisions", "100"), True),
    Bench("amat", "bench_amat.py", ("--repeats", "30", "--train-steps", "3", "--bf16-steps", "1"), False),
    Bench("train", "bench_train.py", ("--iterations", "2", "--epochs", "2"), False),
    Bench("scaling", "bench_scaling.py", ("--seconds", "0.5"), True),
)
NAMES = tuple(b.name for b in BENCHES)


@dataclass
class RunStatus:
    """What happened to one benchmark in this invocation."""

    name: str
    ran: bool = False
    ok: bool = False
    returncode: int | None = None
    seconds: float = 0.0
    command: str = ""
    error: str = ""  # last lines of output when it failed


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


# -- targets -------------------------------------------------------------------------------------------
@dataclass
class Check:
    """One headline number; ``target`` None = context only."""

    bench: str
    label: str
    value: float | None
    unit: str
    target: float | None = None
    op: str = ">="  # ">=", "<=" or "<"
    note: str = ""
    comparable: bool = True  # False: measured in a setting the target does not refer to

    @property
    def met(self) -> bool | None:
        if self.target is None or self.value is None or not self.comparable:
            return None
        return {
            ">=": self.value >= self.target,
            "<=": self.value <= self.target,
            "<": self.value < self.target,
        }[self.op]

    @property
    def status(self) -> str:
        if self.target is None:
            return ""
        if self.value is None:
            return "not measured"
        if not self.comparable:
            return "n/a"
        return "met" if self.met else "**unmet**"

    @property
    def ratio(self) -> float | None:
        """measured / target oriented so that >= 1 means met."""
        if self.met is None or not self.value or not self.target:
            return None
        return self.value / self.target if self.op == ">=" else self.target / self.value


def _find(rows: list[dict], **want: Any) -> dict | None:
    for r in rows:
        if all(r.get(k) == v for k, v in want.items()):
            return r
    return None


def _get(row: dict | None, key: str) -> float | None:
    return None if row is None or row.get(key) is None else float(row[key])


def _setting(overrides: dict) -> str:
    if not overrides:
        return "full comm"
    return ", ".join(f"{k}={v}" for k, v in overrides.items())


def engine_checks(d: dict) -> list[Check]:
    rows = d.get("engine", [])
    out = []
    for preset, target in (("task2", 100_000), ("task3", 40_000)):
        r = _find(rows, preset=preset, num_worlds=64, overrides={})
        out.append(Check("engine", f"{preset}, B = 64, full comm", _get(r, "world_ticks_per_s"),
                         "world-ticks/s", target))  # fmt: skip
    for preset in ("task2", "task3"):
        r = next(
            (r for r in rows if r["preset"] == preset and r["num_worlds"] == 64 and r["overrides"]), None
        )
        if r is not None:
            label = f"{preset}, B = 64, {_setting(r['overrides'])}"
            out.append(Check("engine", label, r["world_ticks_per_s"], "world-ticks/s"))
    pz = d.get("pettingzoo", [])
    worst = min(pz, key=lambda r: r["ticks_per_s"]) if pz else None
    label = "PettingZoo adapter, slowest setting"
    if worst:
        label += f" ({worst['preset']}, {_setting(worst['overrides'])})"
    out.append(Check("engine", label, _get(worst, "ticks_per_s"), "ticks/s", 5_000))
    if d.get("startup_s_cached") is not None:
        out.append(Check("engine", "fresh process start (numba cache warm)", d["startup_s_cached"], "s"))
    return out


def events_checks(d: dict) -> list[Check]:
    rows = d.get("engine", [])
    out = []
    for act in ([0, 0], [2, 5]):
        r = _find(rows, preset="task2", num_worlds=64, activation=act)
        note = f"{r['events_per_s']:,.0f} decision events/s" if r else ""
        out.append(Check("events", f"event engine task2, B = 64, activation {tuple(act)}",
                         _get(r, "world_ticks_per_s"), "world-ticks/s", 50_000, note=note))  # fmt: skip
    pz = d.get("pettingzoo", [])
    worst = min(pz, key=lambda r: r["events_per_s"]) if pz else None
    label = "PettingZoo macro adapter, slowest setting"
    if worst:
        label += f" ({worst['preset']}, activation {tuple(worst['activation'])})"
    note = f"{worst['world_ticks_per_s']:,.0f} world-ticks/s" if worst else ""
    out.append(Check("events", label, _get(worst, "events_per_s"), "decision events/s", 3_000, note=note))
    for r in d.get("planners", []):
        target = 20.0 if r["planner"] == "rrt" else 1.0
        out.append(Check("events", f"planner {r['planner']} ({r['preset']})", r["ms_per_decision"],
                         "ms/decision", target, "<"))  # fmt: skip
    return out


def amat_checks(d: dict, scaling: dict | None) -> list[Check]:
    lat = d.get("latency", [])
    out = []
    for n, s in ((2, 15), (3, 20), (6, 32)):
        r = _find(lat, robots=n, map=s, active=n)
        out.append(Check("amat", f"batch-1 decision (torch), N = {n}, S = {s}, all active",
                         _get(r, "decision_ms"), "ms"))  # fmt: skip
        target = 1.5 if n == 6 else None
        out.append(Check("amat", f"batch-1 decision (FastAmat), N = {n}, S = {s}, all active",
                         _get(r, "fast_decision_ms"), "ms", target, "<="))  # fmt: skip
    if scaling:
        r = _find(scaling.get("curves", {}).get("team_size", []), robots=6, map=32)
        if r is not None and r.get("fast_amat_ms") is not None:
            out.append(Check("amat", "FastAmat batch-1, N = 6, S = 32 (scaling run)", r["fast_amat_ms"],
                             "ms", 1.5, "<="))  # fmt: skip
    for r in d.get("acting", []):
        out.append(Check("amat", f"batched acting, B = {r['worlds']}", r["agent_decisions_per_s"],
                         "agent-decisions/s"))  # fmt: skip
    for r in d.get("training", []):
        best = r.get("best_agent_samples_per_s")
        parts = [f"median step; best {best:,.0f}/s"] if best else []
        parts.append(r.get("batch", "random maps"))
        if r.get("cpu_steal_pct") is not None:
            parts.append(f"CPU steal {r['cpu_steal_pct']:.0f} %")
        label = f"training step {r['precision']}, {r['worlds']}x{r['robots']} batch"
        if r.get("processes", 1) > 1:
            label += f", {r['processes']} processes x 1 thread"
        rate = r["agent_samples_per_s"]
        out.append(Check("amat", label, rate, "agent-samples/s", 5_000, note="; ".join(parts)))
    if not lat and not d.get("training"):
        out.append(Check("amat", "batch-1 decision, N = 6, S = 32, all active", None, "ms", 1.5, "<="))
    return out


def train_checks(d: dict) -> list[Check]:
    runs = d.get("runs", [])
    out = []
    precisions = sorted({r.get("precision", "fp32") for r in runs}, key=lambda p: (p != "fp32", p))
    for precision in precisions or ["fp32"]:
        mine = [r for r in runs if r.get("precision", "fp32") == precision]
        tag = "" if precision == "fp32" else f" [{precision}]"
        r10 = _find(mine, epochs=10)
        r2 = _find(mine, epochs=2)
        worlds = (r10 or r2 or {}).get("num_worlds", 64)
        paper = worlds == 64
        why = "" if paper else f"measured with {worlds} worlds, the target is for 64"
        if r10 is not None:
            out.append(Check("train", f"paper-recipe iteration (10 epochs){tag}", r10["iteration_s"], "s",
                             15.0, "<=", note=why, comparable=paper))  # fmt: skip
        elif r2 is not None:  # extrapolate: collection + advantages + 5x the 2-epoch update
            est = r2["collect_s"] + r2["advantage_s"] + 5 * r2["update_s"]
            note = "estimated from the 2-epoch run (update x 5)" + (f"; {why}" if why else "")
            out.append(Check("train", f"paper-recipe iteration (10 epochs){tag}, est.", est, "s", 15.0, "<=",
                             note=note, comparable=paper))  # fmt: skip
        else:
            out.append(Check("train", f"paper-recipe iteration (10 epochs){tag}", None, "s", 15.0, "<="))
        if precision == "fp32":
            first = r10 or r2
            out.append(Check("train", "collection of 64 episodes", _get(first, "collect_s"), "s", 2.0, "<=",
                             note=why, comparable=paper))  # fmt: skip
        ev = _get(r2, "events_per_s")
        note = f"{r2['world_ticks_per_s']:,.0f} world-ticks/s" if r2 and "world_ticks_per_s" in r2 else ""
        if r2 is not None and ev is None:
            note = "this train.json predates the env-steps/s fields; re-run bench_train.py"
        if why:
            note = f"{note}; {why}" if note else why
        out.append(Check("train", f"env-steps/s end to end, 2 epochs{tag}", ev, "decision events/s", 1_000,
                         note=note, comparable=paper))  # fmt: skip
        for r in mine:  # other recipes: context only
            if r.get("epochs") not in (2, 10):
                note = f"collect {r['collect_s']:.1f} s, update {r['update_s']:.1f} s"
                label = f"iteration, {r['epochs']} epochs, {r.get('num_worlds', 64)} worlds{tag}"
                out.append(Check("train", label, r["iteration_s"], "s", note=note))
    return out


def all_checks(results: dict[str, dict]) -> list[Check]:
    out: list[Check] = []
    if "engine" in results:
        out += engine_checks(results["engine"])
    if "events" in results:
        out += events_checks(results["events"])
    if "amat" in results:
        out += amat_checks(results["amat"], results.get("scaling"))
    if "train" in results:
        out += train_checks(results["train"])
    return out


# -- the summary -----------------------------------------------------------------------------------------
TITLES = {
    "engine": "Primitive engine (`bench_engine.py`, 1 thread)",
    "events": "Event engine and planners (`bench_events.py`, 1 thread)",
    "amat": "AMAT (`bench_amat.py`)",
    "train": "Training iterations (`bench_train.py`, 2 threads)",
    "scaling": "Scaling (`bench_scaling.py`, 1 thread, B = 64 for the engines)",
}


def _num(v: float | None, unit: str = "") -> str:
    if v is None:
        return "—"
    if unit in ("ms", "s", "ms/decision"):
        return f"{v:.3g} {unit}" if v < 10 else f"{v:,.1f} {unit}"
    return f"{v:,.0f} {unit}".strip()


def _target(c: Check) -> str:
    return (
        "" if c.target is None else f"{c.op} {_num(c.target, c.unit)}".replace(">=", "≥").replace("<=", "≤")
    )


def _machine_line() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg()) if hasattr(os, "getloadavg") else "?"
    return f"{cpu}, {os.cpu_count()} logical CPUs, Python {platform.python_version()}; load average {load}"


def load_results(out_dir: Path, names: tuple[str, ...] = NAMES) -> dict[str, dict]:
    results = {}
    for name in names:
        path = out_dir / f"{name}.json"
        if path.exists():
            try:
                results[name] = json.loads(path.read_text())
            except json.JSONDecodeError as exc:
                print(f"warning: {path} is not valid JSON ({exc}); left out of the summary")
    return results


def scaling_table(d: dict) -> list[str]:
    """Wall-clock figures, per CPU second of the benchmark process in parentheses where recorded."""
    curves = d.get("curves", {})
    fast = any(r.get("fast_amat_ms") is not None for c in curves.values() for r in c)

    def cell(r: dict, wall: str, cpu: str, unit: str = "") -> str:
        text = _num(r.get(wall), unit)
        return text + (f" ({_num(r[cpu], unit)})" if r.get(cpu) is not None else "")

    cols = ["S", "N", "engine world-ticks/s", "event engine decisions/s", "AMAT batch-1"]
    cols += ["FastAmat batch-1"] if fast else []
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for axis in ("map_size", "team_size"):
        for r in curves.get(axis, []):
            cells = [str(r["map"]), str(r["robots"])]
            cells += [cell(r, "engine_world_ticks_per_s", "engine_world_ticks_per_cpu_s")]
            cells += [cell(r, "events_per_s", "events_per_cpu_s"), cell(r, "amat_ms", "amat_cpu_ms", "ms")]
            cells += [cell(r, "fast_amat_ms", "fast_amat_cpu_ms", "ms")] if fast else []
            lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "Wall clock; in parentheses per CPU second (CPU ms) of the benchmark process."]
    note = d.get("fast_amat", {}).get("note")
    if note and not fast:
        lines += ["", f"FastAmat curve skipped: {note}"]
    return lines


def write_summary(
    out_dir: Path, statuses: dict[str, RunStatus] | None = None, quick: bool = False
) -> tuple[Path, Path | None]:
    """SUMMARY.md (+ summary.png when matplotlib is there) from the JSON files in ``out_dir``."""
    out_dir = Path(out_dir)
    statuses = statuses or {}
    failed = {n for n, s in statuses.items() if s.ran and not s.ok}
    results = {k: v for k, v in load_results(out_dir).items() if k not in failed}
    checks = all_checks(results)
    met = [c for c in checks if c.met is True]
    unmet = [c for c in checks if c.met is False]
    lines = [
        "# Benchmark summary",
        "",
        f"{datetime.now():%Y-%m-%d %H:%M}; {_machine_line()}."
        + (" **Quick settings** (`run_all.py --quick`): short timings, noisier numbers." if quick else ""),
        "",
        f"Targets: **{len(met)} met, {len(unmet)} unmet** of {len(met) + len(unmet)} measured.",
        "",
    ]
    for name in NAMES:
        st = statuses.get(name)
        lines += [f"## {TITLES[name]}", ""]
        if name in failed:
            assert st is not None
            lines += [f"**FAILED** after {st.seconds:.0f} s: `{st.command}`", "", "```", st.error, "```", ""]
            continue
        if name not in results:
            lines += ["Not run (no JSON).", ""]
            continue
        path = out_dir / f"{name}.json"
        if st is None or not st.ran:
            when = datetime.fromtimestamp(path.stat().st_mtime)
            lines += [f"_From an earlier run ({when:%Y-%m-%d %H:%M})._", ""]
        elif st.ran:
            lines += [f"_Ran in {st.seconds:.0f} s: `{st.command}`._", ""]
        if name == "scaling":
            lines += scaling_table(results[name]) + [""]
            continue
        mine = [c for c in checks if c.bench == name]
        lines += ["| measure | measured | target | status | note |", "|---|---|---|---|---|"]
        for c in mine:
            lines.append(f"| {c.label} | {_num(c.value, c.unit)} | {_target(c)} | {c.status} | {c.note} |")
        lines.append("")
    png = None
    try:
        png = plot_summary(results, checks, out_dir / "summary.png")
        lines += ["![summary](summary.png)", ""]
    except ImportError as exc:
        lines += [f"(summary.png not drawn: {exc})", ""]
    md = out_dir / "SUMMARY.md"
    tmp = md.with_suffix(".md.tmp")
    tmp.write_text("\n".join(lines))
    tmp.replace(md)
    print(f"wrote {md}")
    write_json(
        out_dir / "run_all.json",
        {
            "statuses": {n: asdict(s) for n, s in statuses.items()},
            "checks": [asdict(c) | {"met": c.met, "status": c.status} for c in checks],
        },
    )
    return md, png


def _short(c: Check) -> str:
    """Bar label: bench and measure without parenthesised details."""
    return f"{c.bench}: " + re.sub(r" \([a-z][^)]*\)", "", c.label)


def plot_summary(results: dict[str, dict], checks: list[Check], path: Path) -> Path:
    """Scaling curves (top, 2x2) and every target as measured / target (bottom)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    targeted = [c for c in checks if c.ratio is not None]
    fig = plt.figure(figsize=(11, 8 + 0.25 * max(len(targeted), 4)), layout="constrained")
    top_fig, bar_fig = fig.subfigures(2, 1, height_ratios=[8, 0.25 * max(len(targeted), 4)])
    axes = top_fig.subplots(2, 2)
    scaling = results.get("scaling", {})
    plot_scaling_panels(axes, scaling.get("curves", {}), scaling.get("settings", {}).get("num_worlds", 64))
    ax = bar_fig.subplots()
    if targeted:
        ratios = [c.ratio for c in targeted]
        colors = ["tab:green" if c.met else "tab:red" for c in targeted]
        ypos = range(len(targeted))
        ax.barh(ypos, ratios, color=colors)
        ax.set_yticks(ypos, [_short(c) for c in targeted], fontsize=7)
        ax.invert_yaxis()
        ax.axvline(1.0, color="k", lw=1)
        ax.set_xscale("log")
        for y, c, r in zip(ypos, targeted, ratios):
            ax.text(r, y, f" {_num(c.value, c.unit)} ({_target(c)})", va="center", fontsize=7)
        ax.set_xlabel("measured vs target (> 1 = met; for time targets: target / measured)")
        ax.set_xlim(min(min(ratios) / 2, 0.5), max(max(ratios) * 40, 2))
    else:
        ax.set_axis_off()
        ax.text(0.5, 0.5, "no targets measured", ha="center", va="center", transform=ax.transAxes)
    ax.set_title("Headline figures against their targets", fontsize=10)
    tmp = path.with_name(path.stem + ".tmp.png")
    fig.savefig(tmp, dpi=90)
    plt.close(fig)
    tmp.replace(path)
    print(f"wrote {path}")
    return path


# -- CLI ---------------------------------------------------------------------------------------------------
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
