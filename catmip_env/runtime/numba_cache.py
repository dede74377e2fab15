"""Numba's on-disk cache kept in step with the sources of a package.

Numba keys a cached kernel on its own source file only: when a kernel calls one from another module
(the dynamics call the sensing kernels, FastAmat calls ``kernels.conv``) and only the callee's file
changes, the caller's cache still holds the old callee compiled in, and runs it. :func:`refresh` closes
that gap, once per import of a package: it hashes the package's kernel sources (every file that imports
numba or uses ``njit`` or a ``@kernel`` decorator; a docstring naming numba does not count) and, when the hash
differs from the one recorded with the caches, deletes the package's cached kernels (they recompile on
first use) and records the new hash. An installed package never changes, so it never pays; an edit
to a file without kernels costs no recompilation.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from catmip_env.runtime.files import atomic_path

__all__ = ["refresh"]

STAMP = "numba_sources.sha256"


KERNEL_MARKS = (b"import numba", b"from numba", b"njit", b"@kernel")  # code, not a docstring's mention


def sources_digest(root: Path) -> str:
    """SHA-256 of the kernel sources under ``root``: the ``.py`` files that import numba or use ``njit``
    or ``@kernel`` (relative names and contents, in sorted order)."""
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        text = path.read_bytes()
        if any(mark in text for mark in KERNEL_MARKS):
            h.update(str(path.relative_to(root)).encode() + b"\0" + text + b"\0")
    return h.hexdigest()


def refresh(root: str | Path) -> bool:
    """Delete the cached numba kernels (``__pycache__/*.nbi``, ``*.nbc``) under the package folder
    ``root`` if its sources changed since they were recorded; True if it deleted. A folder it cannot
    write (a read-only install) is left as it is."""
    root = Path(root)
    stamp = root / "__pycache__" / STAMP
    digest = sources_digest(root)
    try:
        if stamp.exists() and stamp.read_text() == digest:
            return False
        for cached in [*root.rglob("__pycache__/*.nbi"), *root.rglob("__pycache__/*.nbc")]:
            cached.unlink(missing_ok=True)
        with atomic_path(stamp) as tmp:
            tmp.write_text(digest)
    except OSError:
        return False
    return True
