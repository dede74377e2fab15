"""How a result file is written: atomic writes (``catmip_env.runtime.files.atomic_path``, with an fsync
before the rename) of text, CSV and figures, and CSV logs that a running job appends to. Whether a path may be
written at all is :mod:`~catmip_rl.store.outputs`' question."""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path
from typing import Any

from catmip_env.runtime.files import atomic_path

__all__ = [
    "atomic_write_text",
    "atomic_write_csv",
    "atomic_savefig",
    "open_csv_log",
    "write_csv_row",
]


def atomic_write_text(path: str | Path, text: str) -> Path:
    with atomic_path(path) as tmp, open(tmp, "w") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    return Path(path)


def atomic_write_csv(path: str | Path, rows: list[dict[str, Any]]) -> Path:
    """Rows of dicts with the first row's keys as header."""
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]) if rows else [])
        w.writeheader()
        w.writerows(rows)
        f.flush()
        os.fsync(f.fileno())
    return Path(path)


def atomic_savefig(fig, path: str | Path, dpi: int = 110) -> Path:
    """Save a matplotlib figure (the format from the suffix) atomically, then close it. A PNG is written
    with a palette of 256 colours, which a plot of lines, bands and text needs: about a third of the bytes
    of matplotlib's RGBA, for figures that are committed and stay in every clone."""
    import io

    import matplotlib.pyplot as plt
    from PIL import Image

    with atomic_path(path) as tmp:
        if Path(path).suffix.lower() == ".png":
            buf = io.BytesIO()
            fig.savefig(buf, dpi=dpi, format="png", facecolor="white")
            rgb = Image.open(buf).convert("RGB")
            rgb.quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(tmp, format="png", optimize=True)
        else:
            fig.savefig(tmp, dpi=dpi)
    plt.close(fig)
    return Path(path)


def open_csv_log(path: Path, fields: list[str], resume_iteration: int | None, key: str = "iteration"):
    """An appending CSV writer; on resume the rows past ``resume_iteration`` (in column ``key``) are
    dropped first, so that a resumed run's log continues where its checkpoint stopped."""
    rows = []
    if resume_iteration is not None and path.exists():
        with path.open() as f:
            rows = [r for r in csv.DictReader(f) if int(r[key]) <= resume_iteration]
    with atomic_path(path) as tmp, tmp.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    f = path.open("a", newline="")
    return f, csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")


def write_csv_row(writer, file, row: dict) -> None:
    """Write ``row`` (NaN as an empty cell) and flush, so that a log is readable while a run goes on."""
    writer.writerow({k: (v if not (isinstance(v, float) and math.isnan(v)) else "") for k, v in row.items()})
    file.flush()
