"""Model and checkpoint files checked before they are trusted: the archive whole (every member's CRC-32,
which ``torch.load`` does not check), its sizes within bounds before anything is read, the model a
config declares counted before it is built, and a training checkpoint's entries of the right types.
Each failure is a :class:`CheckpointError` (a ``ValueError``) naming the file and the problem.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

import torch

__all__ = [
    "CheckpointError", "MAX_ARCHIVE_BYTES", "MAX_PARAMETERS", "check_archive", "check_model_size",
    "check_training_entries", "check_extra",
]  # fmt: skip

MAX_ARCHIVE_BYTES = 1 << 30
"""The most bytes a model or checkpoint file may unpack to (the shipped models: ~5 MB; a training
checkpoint with its optimiser: ~3x its model)."""
MAX_PARAMETERS = 50_000_000
"""The most parameters a model file may declare (the shipped models: ~1.2 million): larger is refused
before it is built."""


class CheckpointError(ValueError):
    """A file that cannot be read as a checkpoint (the message names it and says why)."""


def check_archive(path: Path) -> None:
    """``path`` is a whole torch archive within :data:`MAX_ARCHIVE_BYTES`: members stored as torch
    writes them, their CRC-32s intact (a file with flipped bytes is refused, not loaded)."""
    try:
        with zipfile.ZipFile(path) as archive:
            members = archive.infolist()
            size = sum(m.file_size for m in members)
            if size > MAX_ARCHIVE_BYTES:
                raise CheckpointError(
                    f"{path} unpacks to {size:,} bytes, more than a model file may "
                    f"({MAX_ARCHIVE_BYTES:,}); refused before reading it"
                )
            packed = [m.filename for m in members if m.compress_type != zipfile.ZIP_STORED]
            if packed:
                raise CheckpointError(f"{path} holds compressed members ({packed[0]}): not a torch archive")
            bad = archive.testzip()
    except (zipfile.BadZipFile, EOFError, OSError, RuntimeError, NotImplementedError) as err:
        raise CheckpointError(f"{path} is truncated or corrupted ({type(err).__name__}: {err})") from None
    if bad is not None:
        raise CheckpointError(
            f"{path} is corrupted: its member {bad} fails its checksum (the file was damaged after it was "
            "written; use an intact copy)"
        )


def check_model_size(make_model, config, path: Path) -> None:
    """The model ``make_model(config)`` would build, counted on the meta device (nothing allocated):
    refused with the count when it exceeds :data:`MAX_PARAMETERS`."""
    with torch.device("meta"):
        count = sum(p.numel() for p in make_model(config).parameters())
    if count > MAX_PARAMETERS:
        raise CheckpointError(
            f"{path} declares a model of {count:,} parameters, more than a model file may "
            f"({MAX_PARAMETERS:,}); refused before building it"
        )


_TYPES: dict[str, tuple[type, ...]] = {
    "iteration": (int,), "episodes": (int,), "elapsed_s": (int, float), "bf16": (bool, type(None)),
    "model": (dict,), "amat_config": (dict,), "optimizer": (dict,), "value_norm": (dict,),
    "generator": (torch.Tensor,), "torch_rng": (torch.Tensor,), "config": (str,),
}  # fmt: skip
_EXTRA_TYPES: dict[str, tuple[type, ...]] = {
    "iteration": (int,), "episodes": (int,), "training_minutes": (int, float),
    "total_training_minutes": (int, float), "train_config": (dict,), "init_from": (dict,),
    "value_norm": (dict,), "half": (bool,),
}  # fmt: skip


def check_training_entries(blob: dict, path: Path) -> None:
    """A training checkpoint's entries of the types :func:`~catmip_rl.checkpoint.save_training_checkpoint`
    writes (``config``: the training config's JSON object); ``elapsed_s`` and ``bf16`` may be absent."""
    _check_types(blob, _TYPES, path, "")
    if blob.get("iteration", 0) < 0 or blob.get("episodes", 0) < 0:
        raise CheckpointError(f"{path}: iteration and episodes must be >= 0")
    try:
        ok = isinstance(json.loads(blob.get("config", "{}")), dict)
    except ValueError:
        ok = False
    if not ok:
        raise CheckpointError(f"{path}: its config is not a training config's JSON object")


def check_extra(extra: Any, path: Path) -> None:
    """A model file's ``extra`` (what :func:`~catmip_rl.checkpoint.export_model` writes) of the right
    types where present (None stands for unknown)."""
    if not isinstance(extra, dict):
        raise CheckpointError(f"{path}: its extra is a {type(extra).__name__}, not a dict")
    _check_types({k: v for k, v in extra.items() if v is not None}, _EXTRA_TYPES, path, "extra ")


def _check_types(blob: dict, types: dict[str, tuple[type, ...]], path: Path, where: str) -> None:
    for key, allowed in types.items():
        if key not in blob:
            continue
        value = blob[key]
        if not isinstance(value, allowed) or (isinstance(value, bool) and bool not in allowed):
            names = " or ".join(t.__name__ for t in allowed)
            raise CheckpointError(
                f"{path}: its {where}{key} is a {type(value).__name__}, not {names} (the file was not "
                "written by catmip, or was edited)"
            )
