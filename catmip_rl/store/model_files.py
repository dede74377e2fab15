"""Model and checkpoint files read, and checked before they are trusted (:func:`read_checkpoint`,
:func:`model_from`): the archive whole (every member's CRC-32, which ``torch.load`` does not check), its
sizes within bounds before anything is read, ``torch.load(weights_only=True)`` (tensors and plain
containers only, never pickled objects), a training checkpoint's entries of the right types, and the
model a config declares counted before it is built and its state dict fitted to it. Each failure is a
:class:`CheckpointError` (a ``ValueError``) naming the file and the problem.
"""

from __future__ import annotations

import json
import math
import zipfile
from pathlib import Path
from typing import Any

import torch

from catmip_rl.amat.config import AmatConfig
from catmip_rl.amat.model import AMAT
from catmip_rl.amat.pointer import make_model

__all__ = [
    "CheckpointError",
    "FORMAT",
    "MAX_ARCHIVE_BYTES",
    "MAX_PARAMETERS",
    "read_checkpoint",
    "model_from",
    "is_training_checkpoint",
    "check_archive",
    "declared_config",
    "check_training_entries",
    "check_extra",
    "check_finite",
    "check_value_norm",
    "PLAY_KEYS",
]

FORMAT = "catmip-amat-v1"
"""The format tag of a model file (:func:`~catmip_rl.store.checkpoint.save_model`)."""
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
    except (zipfile.BadZipFile, EOFError, OSError, RuntimeError, NotImplementedError, ValueError) as err:
        # a damaged directory reads as names that are not UTF-8, offsets past the end, ...: the file named
        why = " ".join(str(err).split())[:200]
        raise CheckpointError(f"{path} is truncated or corrupted ({type(err).__name__}: {why})") from None
    if bad is not None:
        raise CheckpointError(
            f"{path} is corrupted: its member {bad} fails its checksum (the file was damaged after it was "
            "written; use an intact copy)"
        )


def declared_config(fields: Any, path: Path) -> AmatConfig:
    """The :class:`AmatConfig` of the ``fields`` a file declares, and the model ``make_model`` would build
    of it counted on the meta device (nothing allocated): refused when the fields are no valid config,
    or with the count when it exceeds :data:`MAX_PARAMETERS`."""
    try:
        config = AmatConfig.from_dict(fields)
    except (TypeError, ValueError, KeyError, AttributeError) as err:
        raise CheckpointError(f"{path} holds no valid AMAT config: {err}") from None
    with torch.device("meta"):
        count = sum(p.numel() for p in make_model(config).parameters())
    if count > MAX_PARAMETERS:
        raise CheckpointError(
            f"{path} declares a model of {count:,} parameters, more than a model file may "
            f"({MAX_PARAMETERS:,}); refused before building it"
        )
    return config


_TYPES: dict[str, tuple[type, ...]] = {
    "iteration": (int,),
    "episodes": (int,),
    "elapsed_s": (int, float),
    "bf16": (bool, type(None)),
    "bf16_machine": (dict, type(None)),
    "model": (dict,),
    "amat_config": (dict,),
    "optimizer": (dict,),
    "value_norm": (dict,),
    "generator": (torch.Tensor,),
    "torch_rng": (torch.Tensor,),
    "config": (str,),
}
_EXTRA_TYPES: dict[str, tuple[type, ...]] = {
    "iteration": (int,),
    "episodes": (int,),
    "training_minutes": (int, float),
    "total_training_minutes": (int, float),
    "train_config": (dict,),
    "init_from": (dict,),
    "value_norm": (dict,),
    "half": (bool,),
    "play": (dict,),
}


def check_training_entries(blob: dict, path: Path) -> None:
    """A training checkpoint's entries of the types
    :func:`~catmip_rl.store.checkpoint.save_training_checkpoint`
    writes (``config``: the training config's JSON object); ``elapsed_s``, ``bf16`` and ``bf16_machine``
    may be absent. Also: the two random states of the size this torch restores, the value normaliser's
    three finite scalars, and no NaN or infinity in any tensor (weights, optimiser, normaliser)."""
    _check_types(blob, _TYPES, path, "")
    if blob.get("iteration", 0) < 0 or blob.get("episodes", 0) < 0:
        raise CheckpointError(f"{path}: iteration and episodes must be >= 0")
    try:
        ok = isinstance(json.loads(blob.get("config", "{}")), dict)
    except ValueError:
        ok = False
    if not ok:
        raise CheckpointError(f"{path}: its config is not a training config's JSON object")
    elapsed = blob.get("elapsed_s", 0.0)
    if not (math.isfinite(elapsed) and elapsed >= 0):
        raise CheckpointError(f"{path}: its elapsed_s is {elapsed!r}, not a finite number of seconds >= 0")
    for key, fresh in (("generator", torch.Generator().get_state()), ("torch_rng", torch.get_rng_state())):
        state = blob.get(key)
        if state is not None and (state.dtype != fresh.dtype or state.shape != fresh.shape):
            raise CheckpointError(
                f"{path}: its {key} is a {state.dtype} random state of shape {tuple(state.shape)}, not the "
                f"{fresh.dtype} {tuple(fresh.shape)} this torch restores (the file was edited or is foreign)"
            )
    if "value_norm" in blob:
        check_value_norm(blob["value_norm"], path, "value_norm")
    for key in ("model", "optimizer"):
        if key in blob:
            check_finite(blob[key], path, key)


def check_extra(extra: Any, path: Path) -> None:
    """A model file's ``extra`` (what :func:`~catmip_rl.store.checkpoint.export_model` writes) of the right
    types where present (None stands for unknown); its ``play`` options booleans (``"no"`` is no
    answer); its value normaliser as a training checkpoint's."""
    if not isinstance(extra, dict):
        raise CheckpointError(f"{path}: its extra is a {type(extra).__name__}, not a dict")
    _check_types({k: v for k, v in extra.items() if v is not None}, _EXTRA_TYPES, path, "extra ")
    for key, value in (extra.get("play") or {}).items():
        if key in PLAY_KEYS and not isinstance(value, bool):
            raise CheckpointError(
                f"{path}: its extra play {key} is {value!r} (a {type(value).__name__}), not true or false"
            )
    if extra.get("value_norm") is not None:
        check_value_norm(extra["value_norm"], path, "extra value_norm")


PLAY_KEYS = ("loop_guard", "clean_occupancy")
"""The play options a model file's ``extra["play"]`` may set (booleans)."""
_VALUE_NORM_KEYS = ("mean", "mean_sq", "debias")


def check_value_norm(state: Any, path: Path, where: str) -> None:
    """A value normaliser's state dict (:class:`~catmip_rl.training.gae.ValueNorm`): its three scalar
    tensors, finite."""
    if (
        not isinstance(state, dict)
        or sorted(state) != sorted(_VALUE_NORM_KEYS)
        or not all(
            isinstance(state[k], torch.Tensor) and state[k].numel() == 1 and state[k].is_floating_point()
            for k in _VALUE_NORM_KEYS
        )
    ):
        shown = (
            {k: type(v).__name__ for k, v in state.items()}
            if isinstance(state, dict)
            else type(state).__name__
        )
        raise CheckpointError(
            f"{path}: its {where} is not a value normaliser's state (expected the scalar tensors "
            f"{', '.join(_VALUE_NORM_KEYS)}; found {shown})"
        )
    check_finite(state, path, where)


def check_finite(tensors: Any, path: Path, where: str) -> None:
    """No NaN or infinity in any floating tensor of ``tensors`` (nested dicts and lists): the first one
    that has one is named."""
    stack = [(where, tensors)]
    while stack:
        name, value = stack.pop()
        if isinstance(value, torch.Tensor):
            if value.is_floating_point() and value.numel() and not bool(torch.isfinite(value).all()):
                bad = int((~torch.isfinite(value)).sum())
                raise CheckpointError(
                    f"{path}: its tensor {name} holds {bad} NaN or infinite value(s) (a diverged run's "
                    "weights play nothing meaningful: use an earlier checkpoint)"
                )
        elif isinstance(value, dict):
            stack.extend((f"{name}.{k}", v) for k, v in reversed(list(value.items())))
        elif isinstance(value, (list, tuple)):
            stack.extend((f"{name}[{i}]", v) for i, v in reversed(list(enumerate(value))))


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


def read_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> Any:
    """``torch.load(path, weights_only=True)``, or :class:`CheckpointError` (``FileNotFoundError`` when
    there is no file) saying what is wrong with the file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no checkpoint at {path}" + (" (it is a folder)" if path.is_dir() else ""))
    if zipfile.is_zipfile(path):  # whole, and of bounded size, before torch reads it
        check_archive(path)
    try:
        blob = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as err:  # torch reports a bad file as any of a dozen types (pickle, zip, OS, key...)
        raise CheckpointError(f"{path} is not a readable checkpoint: {_diagnose(path, err)}") from None
    if is_training_checkpoint(blob):
        check_training_entries(blob, path)
    elif isinstance(blob, dict) and blob.get("format") == FORMAT and blob.get("extra") is not None:
        check_extra(blob["extra"], path)
    return blob


def _diagnose(path: Path, err: Exception) -> str:
    """Why ``torch.load`` failed on ``path``, in words (torch's own message can advise
    ``weights_only=False``, which would run any code the file holds: never repeated here)."""
    size = path.stat().st_size
    if size == 0:
        return "the file is empty"
    with open(path, "rb") as f:
        head = f.read(4)
    if head != b"PK\x03\x04":
        return f"not a torch checkpoint (a {size}-byte file that does not start like one)"
    if not zipfile.is_zipfile(path):
        return f"truncated or corrupted (a {size}-byte torch archive without its index)"
    if "weights only" in str(err).lower():
        return "it holds pickled objects other than tensors and plain containers (refused: unsafe to load)"
    return f"corrupted torch archive ({type(err).__name__})"


def is_training_checkpoint(blob: Any) -> bool:
    return isinstance(blob, dict) and "amat_config" in blob and "config" in blob


def model_from(blob: Any, path: Path) -> AMAT:
    """The AMAT of a checkpoint already read from ``path`` (a model file or a training checkpoint)."""
    if isinstance(blob, dict) and "model" in blob and "amat_config" in blob:  # a training checkpoint
        blob = {"format": FORMAT, "config": blob["amat_config"], "state_dict": blob["model"]}
    if not isinstance(blob, dict) or blob.get("format") != FORMAT:
        raise ValueError(f"{path} is not an AMAT checkpoint (expected format {FORMAT!r})")
    config = declared_config(blob["config"], path)  # counted before anything is allocated
    model = make_model(config)
    state = blob.get("state_dict")
    reason = _state_mismatch(state, model.state_dict())  # short: torch's message lists every key
    if not reason:
        try:
            model.load_state_dict(state)
        except (RuntimeError, KeyError, TypeError, AttributeError) as err:
            reason = " ".join(str(err).split())
            reason = reason if len(reason) <= 300 else reason[:300] + " ..."
    if reason:
        raise ValueError(f"checkpoint {path} does not fit the AMAT its config describes: {reason}")
    check_finite(state, path, "state_dict")
    return model


def _state_mismatch(state: Any, expected: dict[str, torch.Tensor], shown: int = 3) -> str:
    """How ``state`` differs from the model's ``expected`` state dict, in one short line (the first
    ``shown`` keys of each kind and their counts; torch's own message lists every key); "" if it fits
    by keys and shapes."""
    if not isinstance(state, dict):
        return f"its state_dict is a {type(state).__name__}, not a dict of tensors"

    def some(keys: list[str]) -> str:
        return ", ".join(keys[:shown]) + (f", ... ({len(keys)} in all)" if len(keys) > shown else "")

    missing = [k for k in expected if k not in state]
    unexpected = [k for k in state if k not in expected]
    resized = [
        f"{k} {tuple(state[k].shape)} vs {tuple(v.shape)}"
        for k, v in expected.items()
        if k in state and getattr(state[k], "shape", None) is not None and state[k].shape != v.shape
    ]
    kinds = {"missing keys": missing, "unexpected keys": unexpected, "shape mismatch": resized}
    return "; ".join(f"{what}: {some(keys)}" for what, keys in kinds.items() if keys)
