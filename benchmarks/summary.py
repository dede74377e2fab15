"""The one-page summary of the benchmark results: SUMMARY.md (headline numbers against their targets),
summary.png (scaling curves and every target as measured / target) and run_all.json."""

from __future__ import annotations

import json
import os
import platform
import re
from dataclasses import asdict
from datetime import datetime
from pathlib import Path

from common import plot_scaling_panels, write_json
from suite import NAMES, RunStatus
from targets import Check, all_checks

from catmip_rl.store.files import atomic_savefig

__all__ = ["TITLES", "load_results", "machine_line", "plot_summary", "scaling_table", "write_summary"]


TITLES = {
    "engine": "Primitive engine (`bench_engine.py`, 1 thread)",
    "events": "Event engine and planners (`bench_events.py`, 1 thread)",
    "amat": "AMAT (`bench_amat.py`)",
    "train": "Training iterations (`bench_train.py`, 2 threads)",
    "scaling": "Scaling (`bench_scaling.py`, 1 thread, B = 64 for the engines)",
    "executor": "Evaluation decisions (`bench_executor.py`, 1 thread)",
    "threads": "Both engines on several threads (`bench_threads.py`)",
    "peer": "One env through its Python API beside POGEMA (`bench_peer.py`, 1 thread)",
}


def _num(v: float | None, unit: str = "") -> str:
    if v is None:
        return "—"
    if unit in ("ms", "s", "ms/decision"):
        return f"{v:.3g} {unit}" if v < 10 else f"{v:,.1f} {unit}"
    if unit.startswith("x"):  # a ratio: 1.67x one thread
        return f"{v:.2f}{unit}"
    return f"{v:,.0f} {unit}".strip()


def _target(c: Check) -> str:
    return (
        "" if c.target is None else f"{c.op} {_num(c.target, c.unit)}".replace(">=", "≥").replace("<=", "≤")
    )


def machine_line() -> str:
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
    # a failed benchmark's targets stay in the count, as not measured (its stale JSON is not read)
    checks = all_checks(results | dict.fromkeys(failed, {}))
    met = [c for c in checks if c.met is True]
    unmet = [c for c in checks if c.met is False]
    missing = [c for c in checks if c.target is not None and c.value is None]
    targets = [c for c in checks if c.target is not None]
    headline = (
        f"Targets: **{len(met)} met, {len(unmet)} unmet, {len(missing)} not measured** of {len(targets)}"
    )
    if len(targets) > len(met) + len(unmet) + len(missing):
        headline += (
            f" ({len(targets) - len(met) - len(unmet) - len(missing)} n/a: measured in another setting)"
        )
    if failed:
        headline += f"; **failed: {', '.join(sorted(failed))}** (its targets are among those not measured)"
    lines = [
        "# Benchmark summary",
        "",
        f"{datetime.now():%Y-%m-%d %H:%M}; {machine_line()}."
        + (" **Quick settings** (`run_all.py --quick`): short timings, noisier numbers." if quick else ""),
        "",
        headline + ".",
        "",
    ]
    for name in NAMES:
        st = statuses.get(name)
        lines += [f"## {TITLES[name]}", ""]
        if name in failed:
            assert st is not None
            lines += [f"**FAILED** after {st.seconds:.0f} s: `{st.command}`", "", "```", st.error, "```", ""]
            lost = ", ".join(c.label for c in checks if c.bench == name and c.target is not None)
            lines += [f"Targets not measured: {lost}.", ""]
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

    # every target gets a bar: measured ones as measured / target, unmeasured ones (a failed or
    # missing benchmark) as a hatched grey bar at 1 marked NOT MEASURED, so none silently disappears
    rows = [c for c in checks if c.ratio is not None or (c.target is not None and c.value is None)]
    height = 0.25 * max(len(rows), 4)
    fig = plt.figure(figsize=(11, 8 + height), layout="constrained")
    top_fig, bar_fig = fig.subfigures(2, 1, height_ratios=[8, height])
    axes = top_fig.subplots(2, 2)
    scaling = results.get("scaling", {})
    plot_scaling_panels(axes, scaling.get("curves", {}), scaling.get("settings", {}).get("num_worlds", 64))
    ax = bar_fig.subplots()
    if rows:
        ratios = [1.0 if c.ratio is None else c.ratio for c in rows]
        colors = ["lightgrey" if c.ratio is None else "tab:green" if c.met else "tab:red" for c in rows]
        ypos = range(len(rows))
        bars = ax.barh(ypos, ratios, color=colors)
        for bar, c in zip(bars, rows):
            if c.ratio is None:
                bar.set_hatch("//")
        ax.set_yticks(ypos, [_short(c) for c in rows], fontsize=7)
        ax.invert_yaxis()
        ax.axvline(1.0, color="k", lw=1)
        ax.set_xscale("log")
        for y, c, r in zip(ypos, rows, ratios):
            text = (
                f" NOT MEASURED ({_target(c)})"
                if c.ratio is None
                else f" {_num(c.value, c.unit)} ({_target(c)})"
            )
            ax.text(r, y, text, va="center", fontsize=7, color="tab:red" if c.ratio is None else "k")
        ax.set_xlabel("measured vs target (> 1 = met; for time targets: target / measured)")
        ax.set_xlim(min(min(ratios) / 2, 0.5), max(max(ratios) * 40, 2))
    else:
        ax.set_axis_off()
        ax.text(0.5, 0.5, "no targets", ha="center", va="center", transform=ax.transAxes)
    ax.set_title("Headline figures against their targets", fontsize=10)
    atomic_savefig(fig, path, dpi=90)
    print(f"wrote {path}")
    return path


# -- CLI ---------------------------------------------------------------------------------------------------
