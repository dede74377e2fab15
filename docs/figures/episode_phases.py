"""Where episodes spend their time and why some are never rescued, from ``catmip eval`` result folders.

    python docs/figures/episode_phases.py out/diag/task3-full out/diag/task3-2 --out docs/figures/task3_phases

An episode has three phases: the search (until a robot first sees the target), the news (until a
rescuer knows where it is: at once with full communication, when a robot that knows meets one with
partial communication) and the rescue (until a rescuer that knows stands next to it). For each result
(method x setting): success by tick 100 and by the horizon, the mean tick each phase ends (over the
episodes that reach it), the share of episodes whose target is found by tick 100, decisions and stalls
per episode, and each unrescued episode's last phase: the target never found, found but no rescuer
told, or a rescuer told but never there. Writes ``OUT.csv``, ``OUT.md`` and ``OUT.png`` (the share of
episodes past each phase's end, by tick).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from catmip_rl.store.files import atomic_savefig, atomic_write_csv, atomic_write_text

PHASES = (("target_found_tick", "target found"), ("rescuer_informed_tick", "a rescuer knows"),
          ("rescue_tick", "rescued"))  # fmt: skip


def load(folder: Path) -> tuple[dict, list[dict]]:
    try:
        return (json.loads((folder / "summary.json").read_text()),
                json.loads((folder / "episodes.json").read_text()))  # fmt: skip
    except (OSError, ValueError) as err:
        sys.exit(f"error: {folder} is not a catmip eval result ({type(err).__name__}: {err})")


def ticks(episodes: list[dict], key: str) -> np.ndarray:
    return np.array([np.nan if e[key] is None else e[key] for e in episodes], float)


def phase_row(summary: dict, episodes: list[dict]) -> dict:
    """One result's row (see the module docstring)."""
    found, told, rescued = (ticks(episodes, k) for k, _ in PHASES)
    lost = np.isnan(rescued)
    n = len(episodes)

    def mean(x: np.ndarray) -> float | None:
        return None if np.all(np.isnan(x)) else float(np.nanmean(x))

    return {
        "setting": summary["label"], "method": summary["method"], "episodes": n,
        "success_by_100": summary["success_by_100"], "success_rate": summary["success_rate"],
        "found_by_100": float(np.mean(found <= 100)), "found_tick": mean(found),
        "news_delay": mean(told - found), "rescue_phase": mean(rescued - told),
        "decisions": float(np.mean([e["decisions"] for e in episodes])),
        "stalls": float(np.mean([e["stalls"] for e in episodes])),
        "lost_never_found": int(np.sum(lost & np.isnan(found))),
        "lost_nobody_told": int(np.sum(lost & ~np.isnan(found) & np.isnan(told))),
        "lost_told_not_there": int(np.sum(lost & ~np.isnan(told))),
    }  # fmt: skip


def markdown(rows: list[dict]) -> str:
    def f(v, digits=1):
        return "–" if v is None else f"{v:.{digits}f}"

    head = (
        "| setting | method | by tick 100 | by the horizon | found by 100 | found at | news after | "
        "rescue after | decisions | stalls | lost: never found / nobody told / told, not there |"
    )
    lines = [head, "|---" * 11 + "|"]
    for r in rows:
        lost = f"{r['lost_never_found']} / {r['lost_nobody_told']} / {r['lost_told_not_there']}"
        lines.append(
            f"| {r['setting']} | {r['method']} | {r['success_by_100']:.3f} | {r['success_rate']:.3f} | "
            f"{r['found_by_100']:.3f} | {f(r['found_tick'])} | {f(r['news_delay'])} | "
            f"{f(r['rescue_phase'])} | {r['decisions']:.0f} | {r['stalls']:.1f} | {lost} |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("results", nargs="+", type=Path, help="catmip eval result folders (searched recursively)")
    ap.add_argument("--out", type=Path, required=True, help="OUT.csv, OUT.md and OUT.png are written")
    args = ap.parse_args()
    folders = sorted({s.parent for root in args.results for s in root.rglob("summary.json")})
    if not folders:
        sys.exit(f"error: no catmip eval result under {', '.join(map(str, args.results))}")
    loaded = [load(f) for f in folders]
    rows = sorted((phase_row(s, e) for s, e in loaded), key=lambda r: (r["setting"], r["method"]))
    atomic_write_csv(args.out.with_suffix(".csv"), rows)
    atomic_write_text(args.out.with_suffix(".md"), markdown(rows))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    settings = sorted({s["label"] for s, _ in loaded})
    methods = sorted({s["method"] for s, _ in loaded})
    colours = dict(zip(methods, plt.get_cmap("tab10").colors))
    fig, axes = plt.subplots(len(settings), 3, figsize=(13, 3.3 * len(settings)), squeeze=False, sharey=True)
    for row, setting in zip(axes, settings):
        for summary, episodes in loaded:
            if summary["label"] != setting:
                continue
            horizon = int(summary["horizon"])
            for ax, (key, title) in zip(row, PHASES):
                t = ticks(episodes, key)
                share = [float(np.mean(t <= k)) for k in range(horizon + 1)]
                ax.plot(range(horizon + 1), share, color=colours[summary["method"]], label=summary["method"])
                ax.set_title(f"{setting}: {title}", fontsize=9)
        for ax in row:
            ax.set_xlabel("tick")
            ax.grid(alpha=0.3)
        row[0].set_ylabel("share of episodes")
        row[0].legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    atomic_savefig(fig, args.out.with_suffix(".png"), dpi=100)
    print(markdown(rows))
    print(f"wrote {args.out.with_suffix('.csv')}, .md and .png")


if __name__ == "__main__":
    main()
