"""What a command does before it plays: the one-time compilation of the numba kernels it plays with
(catmip_env.runtime.warmup), AMAT's execution included (``catmip eval | render | bench | train`` and the demo
call :func:`compile_kernels` first, so that a first run says what it is doing and how long it took
instead of sitting silent); torch's threads and a worker's tie to its parent: ``evaluation.workers``."""

from __future__ import annotations

import sys
from importlib.util import find_spec
from pathlib import Path
from typing import Any, TextIO

from catmip_env.play import play
from catmip_env.runtime import warmup

__all__ = ["compile_kernels", "plays_amat", "command_plays_amat"]


def _play_small_models() -> None:
    from catmip_rl.amat.config import AmatConfig
    from catmip_rl.amat.onboard.execution import AmatExecutor, CellGoalExecutor
    from catmip_rl.amat.pointer import make_model

    for goals, executor in (("window", AmatExecutor), ("cell", CellGoalExecutor)):
        model = make_model(AmatConfig(embed_dim=16, goals=goals, cell_channels=8, cell_layers=2))
        play(warmup.small_engine(goals), executor(model))


def plays_amat(specs: list[str] | None) -> bool:
    """Whether the method specs (``--method`` values, ``NAME=SPEC,SPEC`` included) play an AMAT model;
    None (a command whose methods are its defaults, or training): True."""
    if specs is None:
        return True
    for spec in specs:
        for part in str(spec).split(","):
            part = part.split("=", 1)[-1].strip()
            while part.startswith("sync:"):
                part = part[len("sync:") :]
            if part.startswith(("amat:", "amat-guard:", "amat-clean:")):
                return True
    return False


def command_plays_amat(args: Any) -> bool:
    """Whether a ``catmip`` command's parsed arguments play an AMAT model (:func:`plays_amat` of its
    ``--method`` / ``--methods``; ``train`` and the demo always do)."""
    if getattr(args, "name", None) not in ("eval", "render", "bench"):
        return True
    if getattr(args, "suite", None) == "perf":
        return True
    specs: list[str] = []
    for key in ("methods", "method"):
        value = getattr(args, key, None)
        specs += [value] if isinstance(value, str) else list(value or [])
    return plays_amat(specs)


def compile_kernels(stream: TextIO | None = sys.stderr, amat: bool = True) -> float:
    """Compile (and cache) the env's kernels and AMAT's execution kernels where either is not compiled
    for these sources on this CPU (AMAT's only where ``amat``, a command that plays a model
    (:func:`plays_amat`), and torch is installed: a planner's or a ``py:`` policy's evaluation does not
    wait for kernels it never uses); the seconds it took (0.0 when everything was cached)."""
    seconds = warmup.compile_kernels(stream) or 0.0
    if amat and find_spec("torch") is not None:
        package = Path(__file__).parents[1]  # catmip_rl
        seconds += warmup.compile_once(package, "AMAT's numba kernels", _play_small_models, stream) or 0.0
    return seconds
