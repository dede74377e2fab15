"""Model checkpoints: the state dict and the :class:`AmatConfig` in one file, written atomically, with
the config also beside it as JSON; loadable on CPU whatever device it was saved on.

Files are read and verified by :mod:`catmip_rl.store.model_files` (``torch.load(weights_only=True)`` after the
archive's checks: tensors and plain containers only; a file that is not one raises its
``CheckpointError`` naming the file and the problem). Shipped
models (``catmip_rl/models/amat_NAME.pt``) load by name: ``load_model("task1")``."""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any, NamedTuple

import torch

from catmip_env.runtime.files import atomic_path
from catmip_rl.amat.config import AmatConfig
from catmip_rl.amat.model import AMAT
from catmip_rl.amat.weights import finer_pool, with_hint
from catmip_rl.store.files import atomic_write_text
from catmip_rl.store.model_files import (
    FORMAT,
    CheckpointError,
    is_training_checkpoint,
    model_from,
    read_checkpoint,
)
from catmip_rl.store.shipped import SHIPPED_DIR, model_file, resolve_model, shipped_models

__all__ = [
    "save_model",
    "load_model",
    "atomic_torch_save",
    "resolve_model",
    "shipped_models",
    "SHIPPED_DIR",
    "resume_checkpoint",
    "initial_weights",
    "load_initial_weights",
    "export_model",
    "model_record",
    "ModelPlay",
    "model_play",
]


def atomic_torch_save(obj: Any, path: str | Path) -> Path:
    """``torch.save`` to a temporary file in the same folder, fsync, then rename into place. A failed
    write (a full disk: torch then raises its own error on top of the OSError) is one ``OSError`` naming
    the file; the file there before is kept."""
    try:
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            torch.save(obj, f)
            f.flush()
            os.fsync(f.fileno())
    except (OSError, RuntimeError) as err:
        cause = err if isinstance(err, OSError) else err.__context__
        if not isinstance(cause, OSError):
            raise
        kept = " (the previous one is kept)" if Path(path).exists() else ""
        failed = OSError(f"cannot write {path}{kept}: {cause.strerror or cause}")
        failed.errno = cause.errno
        raise failed from None
    return Path(path)


def save_model(
    model: AMAT, path: str | Path, extra: dict[str, Any] | None = None, half: bool = False
) -> Path:
    """Write ``path`` (torch file: format tag, config, CPU state dict, ``extra``) and ``path``.json.
    ``half`` stores the weights as float16 (half the bytes: a snapshot to commit; loading casts them back
    to float32, a relative change of at most 2^-11 per weight)."""
    state = {k: v.detach().cpu() for k, v in model.state_dict().items()}
    if half:
        state = {k: v.half() if v.is_floating_point() else v for k, v in state.items()}
    blob = {"format": FORMAT, "config": asdict(model.config), "state_dict": state, "extra": extra or {}}
    path = atomic_torch_save(blob, path)
    side = {"format": FORMAT, "config": asdict(model.config)}
    atomic_write_text(path.with_suffix(".json"), json.dumps(side, indent=2))
    return path


def load_model(path: str | Path, map_location: str | torch.device = "cpu") -> AMAT:
    """Rebuild the model (on CPU by default) from a file written by :func:`save_model`, a training
    checkpoint (``RUN_DIR/checkpoints/*.pt``), a training run dir or its ``checkpoints/`` folder (the
    latest checkpoint) or the name of a shipped model (:func:`resolve_model`)."""
    path = model_file(resolve_model(path))
    return model_from(read_checkpoint(path, map_location), path).to(map_location)


class ModelPlay(NamedTuple):
    """How a model file says it plays: ``synchronous``, trained in the synchronous world (Synch-CATMiP:
    every robot decides together every ``max_ma_ticks`` ticks), as its training config says; ``loop_guard``,
    argmax with the loop guard (``extra["play"]["loop_guard"]``: a robot whose last macro-action stalled
    may not choose that goal again); ``clean_occupancy``, a cell-goal model reading which explored cells
    are occupied from its action mask (``extra["play"]["clean_occupancy"]``,
    :func:`~catmip_rl.amat.inputs.clean_occupancy`)."""

    synchronous: bool
    loop_guard: bool
    clean_occupancy: bool = False


def model_play(spec: str | Path) -> ModelPlay:
    """How the model ``spec`` names (anything :func:`load_model` reads) plays, from one read of its file. A
    training checkpoint says only its world; a file without a training config or ``play`` entry (a bare
    :func:`save_model`) plays asynchronously without the guard (``amat-guard:`` turns the guard on)."""
    blob = read_checkpoint(model_file(resolve_model(spec)))
    if is_training_checkpoint(blob):
        train_config, play = json.loads(blob["config"]), {}
    else:
        extra = (blob.get("extra") if isinstance(blob, dict) else None) or {}
        train_config, play = extra.get("train_config") or {}, extra.get("play") or {}
    synchronous = (train_config.get("env_overrides") or {}).get("synchronous", False)
    return ModelPlay(bool(synchronous), bool(play.get("loop_guard")), bool(play.get("clean_occupancy")))


def model_record(spec: str | Path) -> dict[str, Any]:
    """What a model (anything :func:`load_model` reads) says of its training: iterations, episodes,
    training minutes (its run's and with the runs it started from), the training seed and preset or
    config; None for what it does not say (a bare :func:`save_model`)."""
    blob = read_checkpoint(model_file(resolve_model(spec)))
    if is_training_checkpoint(blob):
        config = json.loads(blob["config"])
        state = {
            "iteration": blob["iteration"],
            "episodes": blob["episodes"],
            "training_minutes": blob.get("elapsed_s", 0.0) / 60.0,
        }
    else:
        state = (blob.get("extra") if isinstance(blob, dict) else None) or {}
        config = state.get("train_config") or {}
    keys = ("iteration", "episodes", "training_minutes", "total_training_minutes", "preset", "command")
    record = {k: state.get(k) for k in keys}
    record["seed"] = config.get("seed") if isinstance(config, dict) else None
    return record


# what a training checkpoint must hold to be resumed (save_training_checkpoint writes them all)
_RESUME_KEYS = (
    "iteration",
    "episodes",
    "model",
    "optimizer",
    "value_norm",
    "generator",
    "torch_rng",
    "config",
)


def save_training_checkpoint(
    path: str | Path,
    *,
    iteration: int,
    episodes: int,
    elapsed_s: float,
    bf16: bool | None,
    bf16_machine: dict[str, Any] | None = None,
    model: AMAT,
    optimizer: torch.optim.Optimizer,
    value_norm: torch.nn.Module,
    generator: torch.Generator,
    config: Any,
) -> Path:
    """Write everything a run needs to continue exactly (atomically): the iteration, episodes and
    training seconds so far (a time budget's LR schedule reads them), the precision "auto" chose
    (None: not chosen yet) and the machine it was chosen on (``bf16_machine``: a resumed run keeps the
    choice on the same kind of machine, see :func:`restore_training`), model, optimiser, value
    normaliser, the sampling generator and torch's global RNG, and the
    :class:`~catmip_rl.training.config.TrainConfig` as JSON. ``load_model`` reads the model and its
    ``amat_config`` from the same file."""
    return atomic_torch_save(
        {
            "iteration": iteration,
            "episodes": episodes,
            "elapsed_s": elapsed_s,
            "bf16": bf16,
            "bf16_machine": bf16_machine,
            "model": model.state_dict(),
            "amat_config": config.amat_config().__dict__,
            "optimizer": optimizer.state_dict(),
            "value_norm": value_norm.state_dict(),
            "generator": generator.get_state(),
            "torch_rng": torch.get_rng_state(),
            "config": config.to_json(),
        },
        path,
    )


def restore_training(
    saved: dict,
    model: AMAT,
    optimizer: torch.optim.Optimizer,
    value_norm: torch.nn.Module,
    generator: torch.Generator,
    precision: str,
    machine: dict[str, Any],
) -> tuple[int, int, float, bool | None]:
    """Load a checkpoint of :func:`save_training_checkpoint` into freshly built parts (and torch's
    global RNG); returns (iteration, episodes, training seconds) to continue from, and the update's
    precision the run chose (bf16 or not), kept where the run's ``precision`` setting is ``precision``
    and it was chosen on a ``machine`` like this one (the device's type, the CPU's native bf16);
    otherwise None: it is chosen again (a run moved from a GPU to a CPU, or to a CPU without native
    bf16, where bf16 autocast is emulated and many times slower)."""
    model.load_state_dict(saved["model"])
    optimizer.load_state_dict(saved["optimizer"])
    value_norm.load_state_dict(saved["value_norm"])
    generator.set_state(saved["generator"])
    torch.set_rng_state(saved["torch_rng"])
    config = json.loads(saved["config"])
    # checkpoints from before bf16_machine was recorded: the device type their config names
    chosen_on = saved.get("bf16_machine") or {"device": torch.device(config.get("device", "cpu")).type}
    same_machine = all(machine.get(k) == v for k, v in chosen_on.items())
    bf16 = saved.get("bf16") if config.get("precision", "fp32") == precision and same_machine else None
    return saved["iteration"], saved["episodes"], saved.get("elapsed_s", 0.0), bf16


def _read_training_checkpoint(path: Path) -> dict:
    saved = read_checkpoint(path)
    missing = [k for k in _RESUME_KEYS if not isinstance(saved, dict) or k not in saved]
    if missing:
        raise CheckpointError(f"{path} is not a training checkpoint (it has no {', '.join(missing)})")
    return saved


def resume_checkpoint(run_dir: str | Path) -> dict:
    """The checkpoint ``--resume`` continues from, ``RUN_DIR/checkpoints/latest.pt``. When it is missing
    or unreadable the error names the newest readable ``iter_*.pt`` and how to resume from it (nothing
    is chosen silently), or says that none is readable."""
    latest = Path(run_dir) / "checkpoints" / "latest.pt"
    try:
        return _read_training_checkpoint(latest)
    except (FileNotFoundError, CheckpointError) as err:
        others = sorted(latest.parent.glob("iter_*.pt"), reverse=True)  # newest first
        hint = f"; no checkpoints/iter_*.pt is readable either ({len(others)} tried)" if others else ""
        for path in others:
            try:
                it = _read_training_checkpoint(path)["iteration"]
            except (OSError, CheckpointError):
                continue
            hint = (
                f"; the newest readable checkpoint is {path} (iteration {it}): to continue from it, "
                f"copy it over {latest} and --resume again"
            )
            break
        raise type(err)(f"cannot resume {run_dir}: {err}{hint}") from None


def _origin(path: Path) -> dict | None:
    """``init_from.json`` of the run a training checkpoint belongs to (RUN_DIR/checkpoints/X.pt), if any."""
    source = path.parent.parent / "init_from.json" if path.parent.name == "checkpoints" else None
    return json.loads(source.read_text()) if source is not None and source.is_file() else None


def _minutes_behind(own_minutes: float, origin: dict | None) -> float:
    """Training minutes behind some weights: their run's own and those of every run it started from."""
    return own_minutes + float((origin or {}).get("elapsed_min") or 0.0)


#: AmatConfig fields a run may change from the weights it starts from (none holds weights of its own)
_WEIGHTLESS = ("cell_mask", "teammate_memory", "teammate_heading", "critic")


def initial_weights(spec: str, config: AmatConfig) -> dict[str, Any]:
    """The weights a new run starts from (``TrainConfig.init_from``), read once: ``{"model": state dict,
    "value_norm": state dict or None, "source": {...}}`` from a training checkpoint or run dir (its latest
    checkpoint), a model file or a shipped model's name. The value normaliser (the value head predicts in
    its units) comes from a training checkpoint or a file of :func:`export_model`. ``source`` says where
    they came from: the spec, the file, its SHA-256, the iteration and the training minutes behind the
    weights (counting the runs they came from in turn; None where unknown), and ``pool`` [theirs, ours]
    where a model whose pooled grid divides ``config.pool`` (and is otherwise ``config``) was spread over
    the finer grid (:func:`~catmip_rl.amat.weights.finer_pool`), ``cell_mask`` [theirs, ours] where a
    cell-goal model is to choose among other cells, ``teammate_memory`` / ``teammate_heading`` [theirs, ours]
    where it is to see remembered teammates (or see them moved along their headings; none holds weights),
    ``hint`` [theirs, ours] where a model without a hint is to read a planner's proposals
    (:func:`~catmip_rl.amat.weights.with_hint`: the same function to start with), and ``critic``
    [theirs, ours] where PPO's values are to come from elsewhere (a new state critic starts from its own
    initialisation). Raises ``ValueError`` (the message starts with "init_from") if the file is missing,
    unreadable or not an AMAT of ``config``."""
    try:
        path = model_file(resolve_model(spec))
        blob = read_checkpoint(path)
        model = model_from(blob, path)
    except (OSError, ValueError) as err:
        raise ValueError(f"init_from: {err}") from None
    weights, theirs = model.state_dict(), model.config
    if config.hint and not theirs.hint:  # a model that is to read a planner's proposals: same function
        weights, theirs = with_hint(weights), replace(theirs, hint=config.hint)
    if theirs.pool != config.pool and theirs == replace(config, pool=theirs.pool):
        try:  # only the pooled grid differs: a finer one starts from the coarse model's weights
            weights = finer_pool(weights, theirs.pool, config.pool)
        except ValueError as err:
            raise ValueError(f"init_from {spec!r}: {err}") from None
    elif theirs != replace(  # neither the mask nor the memory holds weights; the critic is new
        config, **{name: getattr(theirs, name) for name in _WEIGHTLESS}
    ):
        there, here = asdict(model.config), asdict(config)
        diff = ", ".join(f"{k} {there[k]!r} there vs {here[k]!r} here" for k in here if there[k] != here[k])
        raise ValueError(
            f"init_from {spec!r} is an AMAT of another configuration ({diff}): set the run's amat fields to "
            "match, or start from another model"
        )
    if is_training_checkpoint(blob):
        state = {
            "iteration": blob["iteration"],
            "training_minutes": blob.get("elapsed_s", 0.0) / 60.0,
            "init_from": _origin(path),
            "value_norm": blob["value_norm"],
        }
    else:  # a model file; export_model's carry their run's state in extra
        state = blob.get("extra") or {}
    own = state.get("training_minutes")
    source = {
        "init_from": spec,
        "file": str(path),
        "sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
        "iteration": state.get("iteration"),
        "elapsed_min": None if own is None else _minutes_behind(own, state.get("init_from")),
    }
    # what the new run changed
    for name in ("pool", "hint", *_WEIGHTLESS):
        if getattr(model.config, name) != getattr(config, name):
            source[name] = [getattr(model.config, name), getattr(config, name)]
    return {"model": weights, "value_norm": state.get("value_norm"), "source": source}


def load_initial_weights(spec: str, model: AMAT, value_norm: torch.nn.Module) -> dict[str, Any]:
    """Load :func:`initial_weights` ``spec`` into a new run's ``model`` (and ``value_norm`` where the
    file has one); returns where they came from (its ``source``)."""
    init = initial_weights(spec, model.config)
    own, critic = model.state_dict(), "state_critic."
    weights = {k: v for k, v in init["model"].items() if k in own or not k.startswith(critic)}
    # a state critic the file lacks keeps the model's own initial weights; one it has and the run
    # does not use is left out
    model.load_state_dict({k: v for k, v in own.items() if k.startswith(critic)} | weights)
    if init["value_norm"] is not None:
        value_norm.load_state_dict(init["value_norm"])
    return init["source"]


def export_model(source: str | Path, out: str | Path, half: bool = False) -> tuple[Path, dict[str, Any]]:
    """Write the model of a training checkpoint or run dir (its latest checkpoint) as a model file
    (:func:`save_model`, what ``catmip_rl/models/`` ships), with the run's state in the file's ``extra``:
    its config (``train_config``), iteration, episodes, training minutes (``training_minutes``: the run's
    own; ``total_training_minutes``: with those of the runs it started from), where it started from
    (``init_from``, its ``init_from.json``), the value normaliser (so that ``--init-from`` the file
    fine-tunes like the checkpoint) and the CPU capability; ``half``: float16 weights (:func:`save_model`).
    Returns (path, extra)."""
    path = model_file(resolve_model(source))
    blob = read_checkpoint(path)
    if not is_training_checkpoint(blob):
        raise CheckpointError(f"{path} is not a training checkpoint (a model file needs no export)")
    if Path(out).resolve() in (path.resolve(), path.with_suffix(".json").resolve()):
        raise ValueError(f"--out {out} would replace the checkpoint it exports; write the model elsewhere")
    model = model_from(blob, path)
    origin, own = _origin(path), float(blob.get("elapsed_s", 0.0)) / 60.0
    extra = {
        "checkpoint": str(path),
        "iteration": int(blob["iteration"]),
        "episodes": int(blob["episodes"]),
        "training_minutes": own,
        "total_training_minutes": _minutes_behind(own, origin),
        "train_config": json.loads(blob["config"]),
        "init_from": origin,
        "value_norm": blob["value_norm"],
        "cpu_capability": torch.backends.cpu.get_cpu_capability(),
    }
    return save_model(model, out, extra=extra | {"half": half}, half=half), extra
