"""The test-split tables of docs/tasks/task2.md and task3.md from the leaderboard's entries: a row per
entry in the leaderboard's order (class, method, success by tick 100 in each of the task's six settings),
as ``catmip leaderboard`` checks and ranks them. With ``--update FILE ...`` the first table after the
paragraph that starts with "**Test split**" is replaced in place (the task is read from the file's name;
README.md: the top of the board between its ``<!-- board -->`` and ``<!-- /board -->`` lines);
otherwise the tables are printed.

    python docs/figures/test_tables.py [--entries leaderboard/entries] \
        [--update docs/tasks/task2.md docs/tasks/task3.md README.md]
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from catmip_rl.benchmark.board_page import board_top, task_table
from catmip_rl.benchmark.entry_check import EntryError, load_entries
from catmip_rl.benchmark.leaderboard import leaderboard_rows
from catmip_rl.store.files import atomic_write_text

TASKS = ("task2", "task3")
ENTRIES = Path(__file__).resolve().parents[2] / "leaderboard" / "entries"


def tables(entries: Path = ENTRIES) -> dict[str, str]:
    """Each task's table, and the README's top of the board, from the test-split entries in ``entries``."""
    rows = leaderboard_rows(load_entries(entries, split="test"))
    return {task: task_table(rows, task) for task in TASKS} | {"README": board_top(rows)}


def replace_board_top(text: str, table: str) -> str:
    """``text`` with what lies between its ``<!-- board -->`` and ``<!-- /board -->`` lines replaced."""
    start, end = text.find("<!-- board -->\n"), text.find("<!-- /board -->")
    if start < 0 or end < start:
        raise ValueError("no '<!-- board -->' ... '<!-- /board -->' lines to put the table between")
    return text[: start + len("<!-- board -->\n")] + table + "\n" + text[end:]


def replace_test_table(text: str, table: str) -> str:
    """``text`` with the first Markdown table after its "**Test split**" paragraph replaced by ``table``."""
    start = re.search(r"^\*\*Test split\*\*", text, flags=re.MULTILINE)
    if start is None:
        raise ValueError("no paragraph starting with '**Test split**' to put the table under")
    old = re.compile(r"^\|.*\|\n(?:^\|.*\|\n?)+", flags=re.MULTILINE).search(text, start.end())
    nxt = re.compile(r"^(?:#{1,3} |\*\*)", flags=re.MULTILINE).search(text, start.end())
    if old is None or (nxt is not None and old.start() > nxt.start()):
        raise ValueError("no table under the '**Test split**' paragraph")
    end = old.end() - (1 if old.group().endswith("\n") else 0)
    return text[: old.start()] + table + text[end:]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--entries", type=Path, default=ENTRIES, help="the leaderboard's entry files")
    ap.add_argument("--update", type=Path, nargs="+", metavar="FILE", help="replace the table in FILE(s)")
    args = ap.parse_args()
    try:
        made = tables(args.entries)
    except (EntryError, OSError) as err:
        sys.exit(f"error: {err}")
    if args.update is None:
        for task, table in made.items():
            print(f"{task}\n\n{table}\n")
        return
    for page in args.update:
        task = page.stem
        if task not in made:
            sys.exit(f"error: {page}: the suite's tasks are {', '.join(TASKS)} (the file's name says which)")
        try:
            replace = replace_board_top if task == "README" else replace_test_table
            text = replace(page.read_text(), made[task])
        except (OSError, ValueError) as err:
            sys.exit(f"error: {page}: {err}")
        atomic_write_text(page, text)
        print(f"updated the test-split table in {page}")


if __name__ == "__main__":
    main()
