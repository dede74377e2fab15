"""catmip_rl: AMAT, the asynchronous multi-agent transformer, trained by PPO on the CATMiP worlds.

The package is grouped by what each part does (``docs/architecture.md`` draws it):

* :mod:`catmip_rl.amat` — the model: :class:`AMAT` (torch, training), ``FastAmat`` (numba, batch-1
  decisions) and the kernels they share;
* :mod:`catmip_rl.training` — the stages of one PPO iteration (collect, GAE, PPO update) and the loop
  that runs them, plus the imitation warm start;
* :mod:`catmip_rl.evaluation` — decentralised execution, the paper's evaluation protocol and figures;
* :mod:`catmip_rl.adapters` — TorchRL (``CatmipEnv``, actor, critic) and Ray: the only modules that
  import TorchRL or Ray;
* :mod:`catmip_rl.checkpoint` — model files and training checkpoints; :mod:`catmip_rl.cli` — ``catmip``.
"""

from __future__ import annotations

from catmip_env import __version__  # one version for the whole distribution (pyproject reads it there)
from catmip_env.compat import install_aliases
from catmip_rl.amat import AMAT, AmatConfig, decision_order
from catmip_rl.checkpoint import load_model, save_model

__all__ = ["AMAT", "AmatConfig", "__version__", "decision_order", "load_model", "save_model"]

# module paths before the package was grouped into amat/ training/ evaluation/ adapters/
install_aliases(
    {
        "catmip_rl.fast_infer": (
            "catmip_rl.amat.fast",
            "catmip_rl.amat.conv_kernels",
            "catmip_rl.amat.numba_ops",
        ),
        "catmip_rl.sparse_conv": "catmip_rl.amat.sparse_conv",
        "catmip_rl.small_attention": "catmip_rl.amat.small_attention",
        "catmip_rl.config": "catmip_rl.training.config",
        "catmip_rl.collect": "catmip_rl.training.collect",
        "catmip_rl.gae": "catmip_rl.training.gae",
        "catmip_rl.ppo": "catmip_rl.training.ppo",
        "catmip_rl.parallel_update": "catmip_rl.training.parallel_update",
        "catmip_rl.imitation": "catmip_rl.training.imitation",
        "catmip_rl.precision": "catmip_rl.training.precision",
        "catmip_rl.heap": "catmip_rl.training.memory",
        "catmip_rl.train": (
            "catmip_rl.training.train",
            "catmip_rl.training.gae",
            "catmip_rl.training.update",
            "catmip_rl.training.ppo",
            "catmip_rl.training.precision",
            "catmip_rl.checkpoint",
            "catmip_rl.files",
        ),
        "catmip_rl.distributed": "catmip_rl.evaluation.execution",
        "catmip_rl.evaluate": (
            "catmip_rl.evaluation.evaluate",
            "catmip_env.decision_stats",
            "catmip_env.play",
        ),
        "catmip_rl.paper": "catmip_rl.evaluation.paper",
        "catmip_rl.env": "catmip_rl.adapters.torchrl_env",
        "catmip_rl.actor": "catmip_rl.adapters.torchrl_actor",
        "catmip_rl.keys": "catmip_rl.adapters.keys",
        "catmip_rl.ray_collect": "catmip_rl.adapters.ray_collect",
    }
)
