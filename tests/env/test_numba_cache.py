"""catmip_env.runtime.numba_cache: a kernel whose callee in another module changed is recompiled, not served
stale from numba's cache."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

from catmip_env.runtime.numba_cache import refresh, sources_digest

CALLER = """
from numba import njit
from pkgx.callee import g

@njit(cache=True)
def f(x):
    return g(x) + 1
"""


def _package(root, refreshes: bool) -> None:
    pkg = root / "pkgx"
    pkg.mkdir()
    init = "from pathlib import Path\nfrom catmip_env.runtime.numba_cache import refresh\n"
    (pkg / "__init__.py").write_text(init + "refresh(Path(__file__).parent)\n" if refreshes else "")
    (pkg / "caller.py").write_text(textwrap.dedent(CALLER))
    _callee(pkg, 2)


def _callee(pkg, factor: int) -> None:
    path = pkg / "callee.py"
    path.write_text(f"from numba import njit\n\n@njit(cache=True)\ndef g(x):\n    return x * {factor}\n")
    os.utime(path, (1e9 + factor, 1e9 + factor))  # a new mtime whatever the clock's resolution


def _f3(root) -> int:
    code = "from pkgx.caller import f; print(f(3))"
    env = dict(os.environ, PYTHONPATH=f"{root}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    return int(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                              check=True).stdout)  # fmt: skip


def test_a_changed_callee_is_recompiled_into_its_callers(tmp_path):
    plain, kept = tmp_path / "plain", tmp_path / "kept"
    plain.mkdir()
    kept.mkdir()
    _package(plain, refreshes=False)
    _package(kept, refreshes=True)
    assert _f3(plain) == 7 and _f3(kept) == 7  # both compiled and cached
    _callee(plain / "pkgx", 3)
    _callee(kept / "pkgx", 3)
    assert _f3(plain) == 7  # numba alone: the caller's cache still holds g(x) = 2x
    assert _f3(kept) == 10  # refreshed: recompiled with g(x) = 3x


def test_refresh_deletes_only_when_the_sources_change(tmp_path):
    pkg = tmp_path / "p"
    (pkg / "__pycache__").mkdir(parents=True)
    (pkg / "a.py").write_text("from numba import njit\n")
    (pkg / "b.py").write_text("y = 1\n")
    cached = pkg / "__pycache__" / "a.f-1.py311.nbi"
    cached.write_text("index")
    assert refresh(pkg) and not cached.exists()  # no record yet: the caches' sources are unknown
    cached.write_text("index")
    assert not refresh(pkg) and cached.exists()  # unchanged sources: the cache stays
    digest = sources_digest(pkg)
    (pkg / "b.py").write_text(
        '"""Compiled by numba elsewhere."""\ny = 2\n'
    )  # no kernel: the caches stay valid
    assert sources_digest(pkg) == digest and not refresh(pkg) and cached.exists()
    (pkg / "a.py").write_text("from numba import njit  # edited\n")
    assert sources_digest(pkg) != digest
    assert refresh(pkg) and not cached.exists()
