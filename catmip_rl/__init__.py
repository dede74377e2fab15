"""catmip_rl: AMAT, the asynchronous multi-agent transformer, trained by PPO on the CATMiP worlds.

The package is grouped by what each part does (``docs/architecture.md`` draws it):

* :mod:`catmip_rl.amat` — the model: :class:`AMAT` (torch, training), ``FastAmat`` (numba, batch-1
  decisions) and the kernels they share;
* :mod:`catmip_rl.training` — the stages of one PPO iteration (collect, GAE, PPO update) and the loop
  that runs them, plus the imitation warm start;
* :mod:`catmip_rl.evaluation` — decentralised execution, the paper's evaluation protocol and figures;
* :mod:`catmip_rl.adapters` — TorchRL (``CatmipEnv``, actor, critic) and Ray: the only modules that
  import TorchRL or Ray;
* :mod:`catmip_rl.store.checkpoint` — model files and training checkpoints; :mod:`catmip_rl.cli` — ``catmip``.
"""

from __future__ import annotations

from importlib.util import find_spec
from pathlib import Path

from catmip_env import __version__  # one version for the whole distribution (pyproject reads it there)
from catmip_env.runtime.numba_cache import refresh

refresh(Path(__file__).parent)  # before any kernel loads its cache (catmip_env.runtime.numba_cache)

__all__ = ["AMAT", "AmatConfig", "__version__", "decision_order", "load_model", "save_model"]

if find_spec("torch") is not None:  # the model and its files need torch; the planners do not
    from catmip_rl.amat.config import AmatConfig
    from catmip_rl.amat.model import AMAT, decision_order
    from catmip_rl.store.checkpoint import load_model, save_model


def __getattr__(name: str):
    """Without torch (an env-only install, whose ``catmip`` plays the planners) the model's names say
    what to install."""
    if name in __all__:
        raise ModuleNotFoundError(
            f"catmip_rl.{name} needs torch: pip install torch==2.13.0 (the CPU wheel), then "
            "pip install 'catmip[rl]'",
            name="torch",
        )
    raise AttributeError(f"module 'catmip_rl' has no attribute {name!r}")
