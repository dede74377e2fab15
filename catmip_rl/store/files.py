"""Result files: atomic writes (``catmip_env.files.atomic_path``, with an fsync before the rename), CSV logs,
and the up-front checks that an output path can be written without losing anything."""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path
from typing import Any

from catmip_env.files import atomic_path

__all__ = [
    "atomic_write_text",
    "atomic_write_csv",
    "atomic_savefig",
    "open_csv_log",
    "write_csv_row",
    "check_new_dir",
    "check_new_file",
    "check_not_dangling",
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


def check_new_dir(
    path: str | Path, what: str, force: bool = False, advice: str = "", ignore: tuple[str, ...] = ()
) -> Path:
    """Raise unless ``path`` can become an output folder without overwriting anything: it does not exist
    (and can be created) or is an empty folder (but for entries named in ``ignore``); ``force`` accepts a
    folder with files too. ``what`` names the path in messages (a flag: ``--out``); ``advice`` replaces
    the default "pick a new folder or pass --force" hint."""
    path = Path(path)
    check_not_dangling(path, what)
    if path.exists() and not path.is_dir():
        raise FileExistsError(f"{what} {path} is a file, not a folder")
    if path.is_dir() and not force:
        entries = sorted(p.name for p in path.iterdir() if p.name not in ignore)
        if entries:
            shown = ", ".join(entries[:4]) + (", ..." if len(entries) > 4 else "")
            hint = advice or "pick a new folder, or pass --force to write into it"
            raise FileExistsError(f"{what} {path} is not empty ({shown}); {hint}")
    _check_creatable(path, what)
    return path


def check_new_file(path: str | Path, what: str, force: bool = False, suffixes: tuple[str, ...] = ()) -> Path:
    """Raise unless ``path`` can be written as a new file: not a folder, ending in one of ``suffixes``
    (if given), not there yet (``force``: overwrite it), in a folder that exists or can be created."""
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"{what} {path} is a folder; give a file path")
    if suffixes and path.suffix.lower() not in suffixes:
        raise ValueError(f"{what} {path}: the file name must end in {' or '.join(suffixes)}")
    if os.path.lexists(path) and not force:  # a dangling symbolic link too
        link = f" (a symbolic link to {os.readlink(path)})" if path.is_symlink() else ""
        raise FileExistsError(f"{what} {path} exists{link}; pick a new name, or pass --force to overwrite it")
    _check_creatable(path.parent, what)
    return path


def _check_creatable(folder: Path, what: str) -> None:
    """``folder`` exists or can be created: its nearest existing ancestor is a folder we may write in."""
    p = folder.absolute()
    while not p.exists():
        check_not_dangling(p, what)
        p = p.parent
    if not p.is_dir():
        raise NotADirectoryError(f"{what} {folder}: {p} is a file, so the folder cannot be created")
    if not os.access(p, os.W_OK | os.X_OK):
        raise PermissionError(f"{what} {folder}: no permission to write in {p}")


def check_not_dangling(path: Path, what: str) -> None:
    """A symbolic link to nothing cannot become a folder (mkdir meets the link): refuse it up front."""
    if path.is_symlink() and not path.exists():
        raise FileExistsError(
            f"{what} {path} is a symbolic link to {os.readlink(path)}, which does not exist; remove the link "
            "or pick another path"
        )
