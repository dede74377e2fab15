"""Every page on the user path is read in one sitting: README.md, docs/*.md and docs/tasks/*.md at most
2,000 words, leaderboard/README.md (the protocol and how to submit) at most 800, counted as ``wc -w``
counts. Measurement history and experiment readings belong in docs/notes/, which has no cap."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
USER_PATH = [
    ROOT / "README.md",
    *sorted((ROOT / "docs").glob("*.md")),
    *sorted((ROOT / "docs" / "tasks").glob("*.md")),
    ROOT / "leaderboard" / "README.md",
]
LIMITS = {ROOT / "leaderboard" / "README.md": 800}


@pytest.mark.parametrize("page", USER_PATH, ids=lambda p: str(p.relative_to(ROOT)))
def test_user_pages_fit_one_sitting(page: Path):
    words = len(page.read_text().split())
    limit = LIMITS.get(page, 2000)
    assert words <= limit, f"{page.relative_to(ROOT)}: {words} words, over {limit}"
