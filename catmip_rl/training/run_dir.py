"""A training run's folder: one writer at a time, the checks before a run starts, and the clean-up when a
new run stops early.

A run holds its folder for as long as it lives (:class:`RunDirLock`): a second ``catmip train`` on it
is refused with the holder's process id. A refused run leaves nothing behind (:func:`check_run` raises
before anything is built or written); a new run stopped by an error or Ctrl-C before its first
checkpoint removes what it wrote (:func:`remove_run_files`), so that its run dir can be used again;
:func:`stopped_note` says which of the two happened.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import torch

from catmip_rl.store.checkpoint import initial_weights, resume_checkpoint
from catmip_rl.store.model_files import CheckpointError, model_from
from catmip_rl.store.outputs import (
    OutputInUse,
    OutputLock,
    check_new_dir,
    check_not_dangling,
    first_missing,
    remove_debris,
)
from catmip_rl.training.config import TrainConfig
from catmip_rl.training.sections import OptimSection

__all__ = [
    "RunDirInUse",
    "RunDirLock",
    "LOCK_NAME",
    "check_run",
    "first_missing",
    "remove_run_files",
    "stopped_note",
    "tensorboard_writer",
]

LOCK_NAME = ".lock"
"""The file in a run dir that its live run holds locked (and names itself in)."""


RunDirInUse = OutputInUse
"""Another live process holds the run dir."""


class RunDirLock(OutputLock):
    """The exclusive hold of a run dir by this process (:class:`~catmip_rl.store.outputs.OutputLock` on
    ``RUN_DIR/.lock``, which stays when released: a dead run never leaves a stale lock, and its run dir
    resumes at once). Creates the run dir if needed: ``created`` is the outermost folder it made (None
    if the run dir existed), and ``release(undo=True)`` removes what acquiring added."""

    def __init__(self, run_dir: str | Path) -> None:
        super().__init__(
            Path(run_dir) / LOCK_NAME,
            f"run dir {run_dir}",
            "wait for that run to end or stop it (its checkpoints resume with --resume)",
            keep_file=True,
        )
        self.created: Path | None = None
        self._new_file = False

    def acquire(self) -> RunDirLock:
        """Hold the run dir, or raise :class:`RunDirInUse` naming the process that holds it."""
        check_not_dangling(self.path.parent, "run dir")
        if self.path.parent.exists() and not self.path.parent.is_dir():
            raise NotADirectoryError(f"run dir {self.path.parent} is a file, not a folder")
        self.created = first_missing(self.path.parent)
        self._new_file = not self.path.exists()
        super().acquire()
        remove_debris(self.path.parent)  # what a killed writer left
        return self

    def release(self, undo: bool = False) -> None:
        """Let the run dir go; ``undo`` (a run refused after acquiring) also removes the folders or the
        lock file that :meth:`acquire` created."""
        if undo and self.created is not None:
            shutil.rmtree(self.created, ignore_errors=True)
        elif undo and self._new_file:
            self.path.unlink(missing_ok=True)
        super().release()

    def check_free(self) -> None:
        """Raise :class:`RunDirInUse` if a live process holds the run dir; hold nothing, leave no trace."""
        self.acquire().release(undo=True)


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
                f"({saved_cfg.amat_config()} on {saved_cfg.env.env_preset}); start a new run dir instead"
            )
        _check_own_checkpoint(run_dir, saved_cfg)
        _check_restorable(saved, run_dir / "checkpoints" / "latest.pt", cfg.optim)
    elif (run_dir / "checkpoints" / "latest.pt").exists():
        raise FileExistsError(
            f"{run_dir} already holds a run; pass --resume to continue it or pick a new dir"
        )
    else:
        check_new_dir(
            run_dir, "run dir", advice="pick a new run dir (or empty this one)", ignore=(LOCK_NAME,)
        )
        if cfg.model.init_from:
            initial_weights(cfg.model.init_from, cfg.amat_config())  # readable, and the same model
    try:
        cuda = torch.device(cfg.device).type == "cuda"
    except RuntimeError:
        raise ValueError(f"device must be cpu, cuda or cuda:N, got {cfg.device!r}") from None
    if cuda and not torch.cuda.is_available():
        raise ValueError(f"device {cfg.device!r} requested but torch sees no CUDA device")
    if cfg.collection.collector == "ray":
        from catmip_rl.adapters.ray_tasks import import_ray

        import_ray(
            "--collector ray"
        )  # ImportError naming the extra to install: the one check, before anything is built
    return saved


def tensorboard_writer(run_dir: Path):
    """A TensorBoard ``SummaryWriter`` into ``run_dir/tensorboard``, or None without tensorboard."""
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:  # tensorboard comes with the rl extra
        return None
    return SummaryWriter(str(run_dir / "tensorboard"))


def _check_restorable(saved: dict, path: Path, optim: OptimSection) -> None:
    """The checkpoint's model, optimiser and value normaliser load into fresh ones (the optimiser of the
    run's ``optim`` section, as ``--resume`` will load them), or a CheckpointError naming ``path``."""
    from catmip_rl.training.gae import ValueNorm
    from catmip_rl.training.ppo import make_optimizer

    model = model_from(saved, path)  # its own error names the file
    try:
        make_optimizer(model, optim).load_state_dict(saved["optimizer"])
        ValueNorm().load_state_dict(saved["value_norm"])
        torch.Generator().set_state(saved["generator"])
    except (RuntimeError, KeyError, ValueError, TypeError, IndexError) as err:
        why = " ".join(str(err).split())
        raise CheckpointError(
            f"{path}: its optimiser or value normaliser does not fit the model ({why[:160]})"
        ) from None


def _check_own_checkpoint(run_dir: Path, saved: TrainConfig) -> None:
    """The checkpoint to resume belongs to the run of ``RUN_DIR/config.json``: the same model, task and
    seed (what a resumed run never changes); another run's checkpoint copied in is refused, so that
    ``--resume`` never rewrites a run's config to a foreign one."""
    path = run_dir / "config.json"
    if not path.exists():
        return  # a run stopped before writing its config: the checkpoint is all there is
    try:
        own = TrainConfig.from_json(path.read_text())
    except (OSError, ValueError, TypeError, KeyError) as err:
        why = " ".join(str(err).split())
        raise ValueError(f"--resume: {path} is not a training config ({why})") from None
    differs = [
        what
        for what, a, b in (
            ("model", own.amat_config(), saved.amat_config()),
            ("task", own.env_config(), saved.env_config()),
            ("seed", own.seed, saved.seed),
        )
        if a != b
    ]
    if differs:
        raise ValueError(
            f"--resume: checkpoints/latest.pt in {run_dir} is another run's (its {' and '.join(differs)} "
            f"differ from {path}); put back this run's checkpoint, or resume the other run in its own dir"
        )


def remove_run_files(run_dir: Path, created: Path | None) -> None:
    """Undo a new run that stopped before its first checkpoint: remove the folders it created, or (its
    run dir was empty before, ``check_run``) everything it wrote in the run dir."""
    if created is not None:
        shutil.rmtree(created, ignore_errors=True)
        return
    for entry in run_dir.iterdir():
        if entry.name == LOCK_NAME:  # still held by this run: left for the next one
            continue
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
