"""The figure tables of docs/notes/reproducing-figures.md and docs/tasks/ are the committed summaries
(docs/figures/paper/figN_summary.csv), as ``docs/figures/paper_tables.py --update`` writes them, and the
splice replaces only the figure's table."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _tables_module():
    path = ROOT / "docs" / "figures" / "paper_tables.py"
    spec = importlib.util.spec_from_file_location("paper_tables", path)
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
