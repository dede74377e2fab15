"""Atomic result files: write a temporary file beside the target, fsync, rename into place."""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path
from typing import Any

__all__ = ["atomic_write_text", "atomic_write_csv", "open_csv_log", "write_csv_row"]


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


def open_csv_log(path: Path, fields: list[str], resume_iteration: int | None, key: str = "iteration"):
    """An appending CSV writer; on resume the rows past ``resume_iteration`` (in column ``key``) are
    dropped first, so that a resumed run's log continues where its checkpoint stopped."""
    rows = []
    if resume_iteration is not None and path.exists():
        with path.open() as f:
            rows = [r for r in csv.DictReader(f) if int(r[key]) <= resume_iteration]
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    tmp.replace(path)
    f = path.open("a", newline="")
    return f, csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")


def write_csv_row(writer, file, row: dict) -> None:
    """Write ``row`` (NaN as an empty cell) and flush, so that a log is readable while a run goes on."""
    writer.writerow({k: (v if not (isinstance(v, float) and math.isnan(v)) else "") for k, v in row.items()})
    file.flush()
