"""Atomic file writes: write a temporary file beside the target, then rename it into place, so that a
reader (or a resumed run) never sees half a file."""

from __future__ import annotations

import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic_path"]


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` to write to; renamed onto ``path`` when the block ends without an
    error, removed otherwise. The name is unique to this process and call (``.NAME.PID-RANDOM.tmpSUFFIX``,
    keeping the suffix for writers that read it, e.g. matplotlib), so two writers of one file never
    share a temporary file: the last rename wins and each rename moves a whole file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}-{secrets.token_hex(4)}.tmp{path.suffix}")
    try:
        yield tmp
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)
