"""catmip_rl: AMAT, the asynchronous multi-agent transformer, and its TorchRL plumbing.

* :class:`AmatConfig`, :class:`AMAT` — the policy/value network (plain ``nn.Module``);
* :mod:`catmip_rl.actor` — TorchRL actor (``forward`` samples, ``get_dist`` re-scores) and critic;
* :mod:`catmip_rl.checkpoint` — ``save_model`` / ``load_model``;
* :mod:`catmip_rl.distributed` — per-neighbourhood execution and message sizes.
"""

from __future__ import annotations

from catmip_env import __version__  # one version for the whole distribution (pyproject reads it there)
from catmip_rl.amat import AMAT, AmatConfig, decision_order
from catmip_rl.checkpoint import load_model, save_model

__all__ = ["AMAT", "AmatConfig", "__version__", "decision_order", "load_model", "save_model"]
