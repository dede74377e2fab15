"""Model checkpoints: the state dict and the :class:`AmatConfig` in one file, written atomically, with
the config also beside it as JSON; loadable on CPU whatever device it was saved on."""

from __future__ import annotations

import json
import os
from dataclasses import asdict
from pathlib import Path
from typing import Any

import torch

from catmip_rl.amat import AMAT, AmatConfig

__all__ = ["save_model", "load_model", "atomic_torch_save"]

FORMAT = "catmip-amat-v1"


def atomic_torch_save(obj: Any, path: str | Path) -> Path:
    """``torch.save`` to a temporary file in the same folder, fsync, then rename into place."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as f:
        torch.save(obj, f)
        f.flush()
        os.fsync(f.fileno())
    tmp.replace(path)
    return path


def save_model(model: AMAT, path: str | Path, extra: dict[str, Any] | None = None) -> Path:
    """Write ``path`` (torch file: format tag, config, CPU state dict, ``extra``) and ``path``.json."""
    state = {k: v.detach().cpu() for k, v in model.state_dict().items()}
    blob = {"format": FORMAT, "config": asdict(model.config), "state_dict": state, "extra": extra or {}}
    path = atomic_torch_save(blob, path)
    side = path.with_suffix(".json")
    tmp = side.with_name(f".{side.name}.tmp")
    tmp.write_text(json.dumps({"format": FORMAT, "config": asdict(model.config)}, indent=2))
    tmp.replace(side)
    return path


def load_model(path: str | Path, map_location: str | torch.device = "cpu") -> AMAT:
    """Rebuild the model (on CPU by default) from a file written by :func:`save_model`, a training
    checkpoint (``RUN_DIR/checkpoints/*.pt``) or a training run dir (its latest checkpoint)."""
    path = Path(path)
    if path.is_dir():
        path = path / "checkpoints" / "latest.pt"
    if not path.is_file():
        raise FileNotFoundError(f"no AMAT checkpoint at {path}")
    blob = torch.load(path, map_location=map_location, weights_only=True)
    if isinstance(blob, dict) and "model" in blob and "amat_config" in blob:  # a training checkpoint
        blob = {"format": FORMAT, "config": blob["amat_config"], "state_dict": blob["model"]}
    if not isinstance(blob, dict) or blob.get("format") != FORMAT:
        raise ValueError(f"{path} is not an AMAT checkpoint (expected format {FORMAT!r})")
    model = AMAT(AmatConfig.from_dict(blob["config"]))
    try:
        model.load_state_dict(blob["state_dict"])
    except RuntimeError as err:
        raise ValueError(f"checkpoint {path} does not fit the AMAT its config describes: {err}") from None
    return model.to(map_location)
