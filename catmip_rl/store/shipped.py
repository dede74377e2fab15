"""The models shipped in ``catmip_rl/models/`` and how a model argument names a file: no torch here, so
that the command line lists them (and an env-only install's ``catmip`` starts)."""

from __future__ import annotations

import hashlib
from pathlib import Path

__all__ = ["SHIPPED_DIR", "shipped_models", "resolve_model", "model_file", "file_sha256"]

SHIPPED_DIR = Path(__file__).parents[1] / "models"  # catmip_rl/models
"""Where the shipped models are: ``amat_NAME.pt`` loads as ``NAME``."""


def shipped_models() -> list[str]:
    """Names of the models shipped in :data:`SHIPPED_DIR` (``amat_task1.pt`` -> ``task1``)."""
    return sorted(p.stem[len("amat_") :] for p in SHIPPED_DIR.glob("amat_*.pt"))


def resolve_model(spec: str | Path) -> Path:
    """The file or run dir ``spec`` names: an existing path, else a shipped model's name (``task1`` ->
    ``catmip_rl/models/amat_task1.pt``); neither raises ``FileNotFoundError`` listing the shipped names."""
    path = Path(spec)
    if path.exists():
        return path
    shipped = SHIPPED_DIR / f"amat_{spec}.pt"
    if path.name == str(spec) and shipped.is_file():  # a bare name, no folder part
        return shipped
    raise FileNotFoundError(
        f"AMAT model {str(spec)!r} does not exist: not a file or run dir, nor a shipped model (shipped: "
        f"{', '.join(shipped_models()) or 'none'})"
    )


def model_file(path: Path) -> Path:
    """The checkpoint file ``path`` names: itself, or a folder's latest checkpoint (a run dir's
    ``checkpoints/latest.pt``, or a checkpoints folder's ``latest.pt``)."""
    if not path.is_dir():
        return path
    for latest in (path / "checkpoints" / "latest.pt", path / "latest.pt"):
        if latest.is_file():
            return latest
    raise FileNotFoundError(
        f"no AMAT checkpoint in the folder {path}: give a training run dir (holding checkpoints/latest.pt), "
        "its checkpoints/ folder, or a .pt file"
    )


def file_sha256(path: str | Path) -> str:
    """SHA-256 of a file's bytes (a model's or a policy's: what a result was played from)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()
