"""The API reference (docs/build_api.py, pdoc): a page per module, and every link in it resolves."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytest.importorskip("pdoc")


@pytest.fixture(scope="module")
def api(tmp_path_factory):
    spec = importlib.util.spec_from_file_location("build_api", ROOT / "docs" / "build_api.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out = tmp_path_factory.mktemp("api")
    index = mod.build(out)
    assert index.exists()
    return out


def test_every_module_has_a_page(api):
    for pkg in ("catmip_env", "catmip_rl"):
        for path in (ROOT / pkg).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            if parts[-1] == "__main__":
                continue
            name = parts[:-1] if parts[-1] == "__init__" else parts
            page = Path(*name).with_suffix(".html")
            assert (api / page).exists(), f"no page for {'.'.join(parts)}"


def test_every_link_resolves(api):
    broken = []
    ids: dict[Path, set[str]] = {}
    for page in sorted(api.rglob("*.html")):
        html = page.read_text()
        for href in re.findall(r'href="([^"]*)"', html):
            if href.startswith(("http://", "https://", "mailto:", "${")) or not href:
                continue
            file, _, anchor = href.partition("#")
            target = (page.parent / file).resolve() if file else page
            if not target.exists():
                broken.append(f"{page.relative_to(api)}: {href}")
                continue
            if anchor and target.suffix == ".html":
                if target not in ids:
                    ids[target] = set(re.findall(r'id="([^"]+)"', target.read_text()))
                if anchor not in ids[target]:
                    broken.append(f"{page.relative_to(api)}: {href} (no such anchor)")
    assert not broken, f"{len(broken)} broken links, e.g. {broken[:5]}"
