"""Atomic result files: write a temporary file beside the target, fsync, rename into place."""

from __future__ import annotations

import csv
import os
from pathlib import Path
from typing import Any

__all__ = ["atomic_write_text", "atomic_write_csv"]


def atomic_write_text(path: str | Path, text: str) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    tmp.replace(path)
    return path


def atomic_write_csv(path: str | Path, rows: list[dict[str, Any]]) -> Path:
    """Rows of dicts with the first row's keys as header."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]) if rows else [])
        w.writeheader()
        w.writerows(rows)
        f.flush()
        os.fsync(f.fileno())
    tmp.replace(path)
    return path
