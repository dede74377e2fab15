"""The one-time compilation of the numba kernels, announced and timed.

The first episode on a machine compiles every kernel it meets (the env's world, macro-actions and
planners: about 50 s on two cores; AMAT's execution in ``catmip_rl``: about 45 s more) and numba
caches them under the package's ``__pycache__``; later runs load them in a second. :func:`compile_once`
does such a compilation up front when it has not been done for these sources on this CPU, saying so and
how long it took, so that a first command does not sit silent (``catmip`` and the demos call
:func:`compile_kernels`). Numba recompiles on another CPU (its cache is keyed on the host's instruction
set), so the record holds the sources' digest and the CPU's name and features.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TextIO

import numpy as np

from catmip_env.config import make_config
from catmip_env.engines.events import EventEngine
from catmip_env.planners.baselines import PLANNERS, make_planner
from catmip_env.planners.window import make_window_planner
from catmip_env.play import play
from catmip_env.runtime.files import atomic_path
from catmip_env.runtime.numba_cache import sources_digest

__all__ = ["compile_kernels", "compile_once", "is_compiled", "small_engine"]

RECORD = "kernels_compiled"


def _fingerprint(package: Path) -> str:
    """What numba's cached machine code depends on: the package's kernel sources and the host CPU."""
    from llvmlite import binding

    cpu = f"{binding.get_host_cpu_name()} {binding.get_host_cpu_features().flatten()}"
    return f"{sources_digest(package)}\n{cpu}\n"


def is_compiled(package: Path) -> bool:
    """Whether :func:`compile_once` has compiled ``package``'s kernels for these sources on this CPU."""
    try:
        return (package / "__pycache__" / RECORD).read_text() == _fingerprint(package)
    except OSError:
        return False


def compile_once(package: Path, what: str, work: Callable[[], object], stream: TextIO | None) -> float | None:
    """Run ``work`` (which compiles ``package``'s kernels) unless :func:`is_compiled` says it was done,
    with a line naming ``what`` on ``stream`` before and after; the seconds it took, or None."""
    if is_compiled(package):
        return None
    if stream is not None:
        print(f"catmip: compiling {what}, once on this machine...", file=stream, flush=True)
    t0 = time.perf_counter()
    work()
    seconds = time.perf_counter() - t0
    try:
        with atomic_path(package / "__pycache__" / RECORD) as tmp:
            tmp.write_text(_fingerprint(package))
    except OSError:  # a read-only install: numba cannot cache there either; the next run compiles again
        pass
    if stream is not None:
        print(f"catmip: compiled {what} in {seconds:.0f} s (cached for later runs)", file=stream, flush=True)
    return seconds


def small_engine(goal_mode: str) -> EventEngine:
    """A one-world 12x12 Task-1 engine reset to its first map: a cheap episode that compiles the kernels."""
    engine = EventEngine(make_config("task1", map_size=12, horizon_ticks=30), 1, seed=0, goal_mode=goal_mode)
    engine.reset(episode_indices=np.arange(1))
    return engine


def _play_every_planner() -> None:
    for name in PLANNERS:
        play(small_engine("cell"), make_planner(name))
    play(small_engine("window"), make_window_planner("nearest"))


def compile_kernels(stream: TextIO | None = sys.stderr) -> float | None:
    """Compile (and cache) the env's kernels if they are not yet: a short episode with every planner in
    both goal modes. Returns the seconds it took, or None when there was nothing to do."""
    return compile_once(Path(__file__).parents[1], "the env's numba kernels", _play_every_planner, stream)
