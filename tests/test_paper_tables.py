"""The figure tables of docs/notes/reproducing-figures.md and docs/tasks/ are the committed summaries
(docs/figures/paper/figN_summary.csv), as ``docs/figures/paper_tables.py --update`` writes them, and the
splice replaces only the figure's table; the task pages' test-split tables are the leaderboard's
entries, as ``docs/figures/test_tables.py --update`` writes them."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _tables_module(name: str = "paper_tables"):
    path = ROOT / "docs" / "figures" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize(
    ("page", "shown"),
    [("notes/reproducing-figures.md", [9, 10]), ("tasks/task1.md", [6]), ("tasks/task2.md", [7, 11]),
     ("tasks/task3.md", [8])],
)  # fmt: skip
def test_the_pages_show_the_committed_summaries(page, shown):
    tables = _tables_module()
    text = (ROOT / "docs" / page).read_text()
    figures = tables.figure_files(ROOT / "docs" / "figures" / "paper")
    assert [n for n, _ in figures] == [6, 7, 8, 9, 10, 11]
    assert sorted(tables.figures_in(text)) == shown
    for n, path in figures:
        if n in shown:
            fresh = tables.replace_table(text, n, tables.table(path, bold=True))
            assert fresh == text, f"figure {n} is stale"


def test_replace_table_changes_only_that_figures_table():
    tables = _tables_module()
    text = (
        "### Figure 6: a\n\n![x](x.png)\n\n| a | b |\n|---|---|\n| 1 | 2 |\n\nprose\n\n"
        "### Figure 7\n\n| c |\n|---|\n| 3 |\n"
    )
    out = tables.replace_table(text, 6, "| a | b |\n|---|---|\n| 5 | 6 |")
    assert out == text.replace("| 1 | 2 |", "| 5 | 6 |")
    out = tables.replace_table(text, 7, "| c |\n|---|\n| 9 |")
    assert out == text.replace("| 3 |", "| 9 |")
    with pytest.raises(ValueError, match="Figure 8"):
        tables.replace_table(text, 8, "| x |")
    with pytest.raises(ValueError, match="no table under"):
        tables.replace_table("### Figure 6\n\nno table\n\n### Figure 7\n\n| c |\n|---|\n", 6, "| x |")


def test_the_task_pages_show_the_leaderboards_test_split():
    """Every committed test-split entry is a row of Task 2's and Task 3's table, in the leaderboard's
    order, with the numbers its rescue ticks give."""
    tables = _tables_module("test_tables")
    made = tables.tables()
    for task in tables.TASKS:
        text = (ROOT / "docs" / "tasks" / f"{task}.md").read_text()
        assert tables.replace_test_table(text, made[task]) == text, f"{task}.md's test-split table is stale"
        rows = made[task].splitlines()[2:]
        assert len(rows) == len(list((ROOT / "leaderboard" / "entries").glob("*.json")))


def test_the_readme_shows_the_top_of_the_committed_board():
    """The README's table is the board's top six ranked rows and its reference rows, generated from the
    committed entries: it never drifts from them."""
    tables = _tables_module("test_tables")
    made = tables.tables()["README"]
    text = (ROOT / "README.md").read_text()
    assert tables.replace_board_top(text, made) == text, "README.md's top of the board is stale"
    rows = made.splitlines()[2:]
    assert rows[0].startswith("| 1 | ") and len([r for r in rows if "| reference |" not in r]) == 6
    with pytest.raises(ValueError, match="no '<!-- board -->'"):
        tables.replace_board_top("no markers", made)


def test_replace_test_table_changes_only_the_test_splits_table():
    tables = _tables_module("test_tables")
    text = "**Test split** (maps):\n\n| a |\n|---|\n| 1 |\n\n**Validation split**\n\n| b |\n|---|\n"
    assert tables.replace_test_table(text, "| a |\n|---|\n| 5 |") == text.replace("| 1 |", "| 5 |")
    with pytest.raises(ValueError, match="no paragraph"):
        tables.replace_test_table("| a |\n|---|\n| 1 |\n", "| x |")
    with pytest.raises(ValueError, match="no table under"):
        tables.replace_test_table("**Test split** none\n\n**Validation split**\n\n| b |\n|---|\n", "| x |")
