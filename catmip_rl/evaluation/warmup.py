"""What a command does before it plays: the one-time compilation of the numba kernels it plays with
(catmip_env.warmup), AMAT's execution included (``catmip eval | render | bench | train`` and the demo
call :func:`compile_kernels` first, so that a first run says what it is doing and how long it took
instead of sitting silent), and torch's thread count where torch is installed (:func:`torch_threads`)."""

from __future__ import annotations

import sys
from importlib.util import find_spec
from pathlib import Path
from typing import TextIO

from catmip_env import warmup
from catmip_env.play import play

__all__ = ["compile_kernels", "torch_threads"]


def _play_small_models() -> None:
    from catmip_rl.amat.config import AmatConfig
    from catmip_rl.amat.pointer import make_model
    from catmip_rl.evaluation.execution import AmatExecutor, CellGoalExecutor

    for goals, executor in (("window", AmatExecutor), ("cell", CellGoalExecutor)):
        model = make_model(AmatConfig(embed_dim=16, goals=goals, cell_channels=8, cell_layers=2))
        play(warmup.small_engine(goals), executor(model))


def compile_kernels(stream: TextIO | None = sys.stderr) -> float:
    """Compile (and cache) the env's kernels and AMAT's execution kernels where either is not compiled
    for these sources on this CPU (AMAT's only where torch is installed: without it no model plays);
    the seconds it took (0.0 when everything was cached)."""
    seconds = warmup.compile_kernels(stream) or 0.0
    if find_spec("torch") is not None:
        package = Path(__file__).parents[1]
        seconds += warmup.compile_once(package, "AMAT's numba kernels", _play_small_models, stream) or 0.0
    return seconds


def torch_threads(n: int) -> None:
    """torch's CPU threads for a command that may play a model; without torch (an env-only install,
    which plays the planners) there is nothing to set, and a model's method fails naming the extra."""
    try:
        import torch
    except ModuleNotFoundError:
        return
    torch.set_num_threads(n)
