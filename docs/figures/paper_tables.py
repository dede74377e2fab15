"""The figure tables of docs/tasks/ and docs/notes/reproducing-figures.md from the summaries ``catmip
bench paper`` wrote: one markdown table per figure, a row per method and a column per panel, each cell
"success by tick 100 / success by the horizon / mean rescue tick"; with ``--bold`` the best by-tick-100
value of each column is bold. With ``--update FILE ...`` the table of each figure a FILE has a heading
for (the first table after a heading that starts with "### Figure N") is replaced in place; otherwise
the tables are printed.

    python docs/figures/paper_tables.py [--dir docs/figures/paper] [--bold] \
        [--update docs/notes/reproducing-figures.md docs/tasks/task*.md]
"""

from __future__ import annotations

import argparse
import csv
import re
import sys
from pathlib import Path

from catmip_rl.benchmark.paper import summary_table
from catmip_rl.store.files import atomic_write_text


def table(path: Path, bold: bool = False) -> str:
    """The markdown table of one ``figN_summary.csv``."""
    with path.open() as f:
        return summary_table(list(csv.DictReader(f)), bold)


def replace_table(text: str, figure: int, new_table: str) -> str:
    """``text`` with the first markdown table after the heading "### Figure ``figure``" replaced."""
    heading = re.search(rf"^### Figure {figure}\b.*$", text, flags=re.MULTILINE)
    if heading is None:
        raise ValueError(f"no heading '### Figure {figure}' to put its table under")
    old = re.compile(r"^\|.*\|\n(?:^\|.*\|\n?)+", flags=re.MULTILINE).search(text, heading.end())
    nxt = re.compile(r"^#{1,3} ", flags=re.MULTILINE).search(text, heading.end())
    if old is None or (nxt is not None and old.start() > nxt.start()):
        raise ValueError(f"no table under '### Figure {figure}'")
    end = old.end() - (1 if old.group().endswith("\n") else 0)
    return text[: old.start()] + new_table + text[end:]


def figures_in(text: str) -> set[int]:
    """The figures a page has a "### Figure N" heading for."""
    return {int(n) for n in re.findall(r"^### Figure (\d+)\b", text, flags=re.MULTILINE)}


def figure_files(folder: Path) -> list[tuple[int, Path]]:
    found = [(int(p.stem[3:].split("_")[0]), p) for p in folder.glob("fig*_summary.csv")]
    return sorted(found)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dir", type=Path, default=Path(__file__).parent / "paper", help="the figN_summary.csv")
    ap.add_argument("--bold", action="store_true", help="bold the best success by tick 100 of each column")
    ap.add_argument("--update", type=Path, nargs="+", metavar="FILE", help="replace the tables in FILE(s)")
    args = ap.parse_args()
    figures = figure_files(args.dir)
    if not figures:
        sys.exit(f"error: no fig*_summary.csv in {args.dir}")
    if args.update is None:
        for n, path in figures:
            print(f"### Figure {n}\n\n{table(path, args.bold)}\n")
        return
    for page in args.update:
        text = page.read_text()
        mine = [(n, path) for n, path in figures if n in figures_in(text)]
        if not mine:
            sys.exit(f"error: {page}: no '### Figure N' heading for any of figures {[n for n, _ in figures]}")
        for n, path in mine:
            text = replace_table(text, n, table(path, args.bold))
        atomic_write_text(page, text)
        print(f"updated {len(mine)} tables in {page}")


if __name__ == "__main__":
    main()
