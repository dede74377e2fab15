"""Every relative link and anchor in the README and docs/ points at something that exists.

Anchors are GitHub's heading slugs: lower case, punctuation other than ``-`` and ``_`` dropped, spaces
turned into ``-``, repeated headings numbered ``-1``, ``-2`` ... Links inside code are not links.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [
    ROOT / "README.md",
    *sorted(p for p in (ROOT / "docs").rglob("*.md") if "api" not in p.relative_to(ROOT / "docs").parts),
    ROOT / "catmip_rl" / "models" / "README.md",
]

LINK = re.compile(r"!?\[(?:[^\]\[]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")
HTML_ANCHOR = re.compile(r"<a\s+(?:id|name)=\"([^\"]+)\"")


def _prose(text: str) -> list[str]:
    """The page's lines outside fenced code blocks, with inline code removed."""
    lines, fenced = [], False
    for line in text.splitlines():
        if line.lstrip().startswith(("```", "~~~")):
            fenced = not fenced
            continue
        lines.append("" if fenced else re.sub(r"`[^`]*`", "", line))
    return lines


def slug(heading: str) -> str:
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link in a heading: its text
    text = re.sub(r"[^\w\- ]", "", text.lower())
    return text.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    found, seen = set(), {}
    fenced = False
    for line in page.read_text().splitlines():
        if line.lstrip().startswith(("```", "~~~")):
            fenced = not fenced
            continue
        if fenced:
            continue
        found.update(HTML_ANCHOR.findall(line))
        m = HEADING.match(line)
        if m:
            base = slug(m.group(2))
            n = seen.get(base, 0)
            seen[base] = n + 1
            found.add(base if n == 0 else f"{base}-{n}")
    return found


def _rel(path: Path) -> Path:
    return path.relative_to(ROOT) if path.is_relative_to(ROOT) else path


def broken_links(page: Path) -> list[str]:
    out = []
    text = "\n".join(_prose(page.read_text()))  # a link's text may wrap onto the next line
    for m in LINK.finditer(text):
        target, lineno = m.group(1), text.count("\n", 0, m.start(1)) + 1
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I):  # http:, https:, mailto: ...
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        where = f"{_rel(page)}:{lineno}: {target}"
        if not dest.exists():
            out.append(f"{where} (no such file)")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            out.append(f"{where} (no such anchor in {_rel(dest)})")
    return out


def test_slugs_follow_github():
    assert (
        slug("Training iterations (`benchmarks/bench_train.py`)")
        == "training-iterations-benchmarksbench_trainpy"
    )
    assert slug("Training on CPU: the sparse global convolution (`catmip_rl.sparse_conv`)") == (
        "training-on-cpu-the-sparse-global-convolution-catmip_rlsparse_conv"
    )
    assert slug("Rewards, success and horizon") == "rewards-success-and-horizon"


def test_checker_finds_broken_links(tmp_path):
    (tmp_path / "a.md").write_text("# A page\n\n## Second `part`\n")
    page = tmp_path / "b.md"
    page.write_text(
        "[ok](a.md) [ok](a.md#second-part) [ok](#b) [external](https://example.org/x.md#nope)\n"
        "`[code](missing.md)`\n```\n[fenced](missing.md)\n```\n# B\n"
        "[bad anchor](a.md#second) [a wrapped\nlink](missing.md)\n"
    )
    assert [b.split(": ", 1)[1] for b in broken_links(page)] == [
        f"a.md#second (no such anchor in {tmp_path / 'a.md'})",
        "missing.md (no such file)",
    ]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(page: Path):
    assert page.exists()
    assert broken_links(page) == []
