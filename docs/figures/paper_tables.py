"""The tables of docs/reproducing.md from the summaries ``catmip bench paper`` wrote: one markdown table per
figure, a row per method and a column per panel, each cell "success by tick 100 / success by the horizon /
mean rescue tick"; with ``--bold`` the best by-tick-100 value of each column is bold.

    python docs/figures/paper_tables.py [--dir docs/figures/paper] [--bold]
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path


def cell(row: dict) -> str:
    tick = row["mean_rescue_tick"]
    rescue = "–" if tick in ("", "None") else f"{float(tick):.0f}"
    return f"{float(row['success_by_100']):.2f} / {float(row['success_rate']):.2f} / {rescue}"


def table(path: Path, bold: bool = False) -> str:
    """The markdown table of one ``figN_summary.csv``."""
    rows = list(csv.DictReader(path.open()))
    panels = list(dict.fromkeys(r["panel"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    at = {(r["method"], r["panel"]): r for r in rows}
    best = {p: max(float(r["success_by_100"]) for r in rows if r["panel"] == p) for p in panels}
    lines = ["| method | " + " | ".join(panels) + " |", "|---" * (len(panels) + 1) + "|"]
    for m in methods:
        cells = []
        for p in panels:
            r = at.get((m, p))
            text = "" if r is None else cell(r)
            if r is not None and bold and float(r["success_by_100"]) == best[p]:
                text = f"**{text}**"
            cells.append(text)
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dir", type=Path, default=Path(__file__).parent / "paper", help="the figN_summary.csv")
    ap.add_argument("--bold", action="store_true", help="bold the best success by tick 100 of each column")
    args = ap.parse_args()
    for path in sorted(args.dir.glob("fig*_summary.csv"), key=lambda p: int(p.stem[3:].split("_")[0])):
        print(f"### Figure {path.stem[3:].split('_')[0]}\n\n{table(path, args.bold)}\n")


if __name__ == "__main__":
    main()
