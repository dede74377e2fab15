"""catmip_env: the CATMiP search-and-rescue world for heterogeneous robot teams (numpy + numba).

* :class:`EnvConfig`, :class:`RobotClass`, :data:`PRESETS` — task definitions (``task1`` ... ``train``);
* :class:`BatchedWorld` — B worlds stepped in one call (struct of arrays, numba kernels);
* :class:`EventEngine` — the same worlds advanced from one decision event to the next (macro-actions);
* :func:`make_planner` — the classical planning baselines (``nearest``, ``rrt``, ...);
* ``search_rescue_v0`` — the PettingZoo Parallel env (``parallel_env()``, ``env()``):
  ``from catmip_env import search_rescue_v0``.

Its folders, by job, lowest first: the base (``constants``, ``config``, ``fields``, ``ascii_maps``) →
``kernels/`` (the numba kernels: maps, sensing, paths, dynamics, macro-actions, observations) →
``engines/`` (:class:`BatchedWorld`, :class:`EventEngine`, episode metrics) → ``maps/`` (the frozen map
sets) and ``planners/`` → ``play`` (the episode loop) → ``runtime/`` (numba's cache, the machine, atomic
files) → ``envs/`` (PettingZoo: the env, its spaces, its frames) → ``demo``.

This package never imports torch.
"""

from __future__ import annotations

from pathlib import Path

from catmip_env.runtime.numba_cache import refresh

refresh(Path(__file__).parent)  # before any kernel loads its cache (catmip_env.runtime.numba_cache)

from catmip_env.ascii_maps import Layout, parse_layout  # noqa: E402
from catmip_env.config import EXPLORER, PRESETS, RESCUER, EnvConfig, RobotClass, make_config  # noqa: E402
from catmip_env.engines.events import EventEngine  # noqa: E402
from catmip_env.engines.world import BatchedWorld, StepResult  # noqa: E402
from catmip_env.envs import search_rescue_v0  # noqa: E402  (the PettingZoo env: catmip_env.search_rescue_v0)
from catmip_env.kernels.state import WorldState  # noqa: E402
from catmip_env.planners.baselines import make_planner  # noqa: E402

__version__ = "1.0.0"

__all__ = [
    "EXPLORER",
    "PRESETS",
    "RESCUER",
    "BatchedWorld",
    "EnvConfig",
    "EventEngine",
    "Layout",
    "RobotClass",
    "StepResult",
    "WorldState",
    "make_config",
    "make_planner",
    "parse_layout",
    "search_rescue_v0",
]


def _register() -> None:
    """Make ``pettingzoo.make("parallel", "catmip/SearchRescue-v0")`` (and ``"aec"``) work."""
    from pettingzoo import aec_registry, parallel_registry, register

    if "catmip/SearchRescue-v0" not in parallel_registry:
        register("parallel", "catmip/SearchRescue-v0", "catmip_env.envs.search_rescue_v0:parallel_env")
    if "catmip/SearchRescue-v0" not in aec_registry:
        register("aec", "catmip/SearchRescue-v0", "catmip_env.envs.search_rescue_v0:env")


_register()
