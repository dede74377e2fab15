"""A training run's folder: the checks before a run starts, and the clean-up when a new run stops early.

A refused run leaves nothing behind (:func:`check_run` raises before anything is built or written); a
new run stopped by an error or Ctrl-C before its first checkpoint removes what it wrote
(:func:`remove_run_files`), so that its run dir can be used again; :func:`stopped_note` says which of
the two happened.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import torch

from catmip_rl.checkpoint import initial_weights, resume_checkpoint
from catmip_rl.files import check_new_dir
from catmip_rl.training.config import TrainConfig

__all__ = ["check_run", "first_missing", "remove_run_files", "stopped_note", "tensorboard_writer"]


def check_run(cfg: TrainConfig, run_dir: Path, resume: bool) -> dict | None:
    """Every refusal, before anything is built or written: the checkpoint to continue (``resume``) must
    be readable and of the same model and task; a new run needs a new or empty run dir, and the weights
    it starts from (``init_from``) must be a readable AMAT of its model config. Also the
    device and, for ``collector="ray"``, the ray package. Returns the checkpoint (None for a new run)."""
    saved = None
    if resume:
        saved = resume_checkpoint(run_dir)
        saved_cfg = TrainConfig.from_json(saved["config"])
        if saved_cfg.amat_config() != cfg.amat_config() or saved_cfg.env_config() != cfg.env_config():
            raise ValueError(
                f"--resume: the checkpoint in {run_dir} was trained with another model or task "
                f"({saved_cfg.amat_config()} on {saved_cfg.env_preset}); start a new run dir instead"
            )
    elif (run_dir / "checkpoints" / "latest.pt").exists():
        raise FileExistsError(
            f"{run_dir} already holds a run; pass --resume to continue it or pick a new dir"
        )
    else:
        check_new_dir(run_dir, "run dir", advice="pick a new run dir (or empty this one)")
        if cfg.init_from:
            initial_weights(cfg.init_from, cfg.amat_config())  # readable, and the same model
    try:
        cuda = torch.device(cfg.device).type == "cuda"
    except RuntimeError:
        raise ValueError(f"device must be cpu, cuda or cuda:N, got {cfg.device!r}") from None
    if cuda and not torch.cuda.is_available():
        raise ValueError(f"device {cfg.device!r} requested but torch sees no CUDA device")
    if cfg.collector == "ray":
        from catmip_rl.adapters.ray_collect import import_ray

        import_ray()  # RuntimeError naming the extra to install
    return saved


def tensorboard_writer(run_dir: Path):
    """A TensorBoard ``SummaryWriter`` into ``run_dir/tensorboard``, or None without tensorboard."""
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:  # tensorboard comes with the rl extra
        return None
    return SummaryWriter(str(run_dir / "tensorboard"))


def first_missing(path: Path) -> Path | None:
    """The outermost folder of ``path`` (itself included) that does not exist yet: what ``mkdir(parents=
    True)`` creates; None if ``path`` exists."""
    missing = None
    for p in (path, *path.parents):
        if p.exists():
            break
        missing = p
    return missing


def remove_run_files(run_dir: Path, created: Path | None) -> None:
    """Undo a new run that stopped before its first checkpoint: remove the folders it created, or (its
    run dir was empty before, ``check_run``) everything it wrote in the run dir."""
    if created is not None:
        shutil.rmtree(created, ignore_errors=True)
        return
    for entry in run_dir.iterdir():
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry, ignore_errors=True)
        else:
            entry.unlink(missing_ok=True)


def stopped_note(run_dir: Path, resume: bool, created: Path | None) -> str:
    """What a stopped run leaves, for the one-line message (added to the exception as a note)."""
    if resume or (run_dir / "checkpoints" / "latest.pt").exists():
        return f"its checkpoints are kept: continue with catmip train --run-dir {run_dir} --resume"
    what = "removed" if created is not None else "emptied"
    return f"stopped before its first checkpoint, so {run_dir} was {what} (nothing to resume; start it again)"
