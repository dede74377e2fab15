"""AMAT, the asynchronous multi-agent transformer.

* ``model`` — :class:`AMAT` (torch ``nn.Module``: training, batched decisions) and :class:`AmatConfig`;
* ``fast`` — ``FastAmat``: the same function for one world's decision event, in numba;
* ``sparse_conv``, ``small_attention`` — hand-written autograd kernels the model uses on CPU.
"""

from __future__ import annotations

from catmip_rl.amat.model import AMAT, INVALID_LOGIT, OBS_SCALE, AmatConfig, decision_order

__all__ = ["AMAT", "INVALID_LOGIT", "OBS_SCALE", "AmatConfig", "decision_order"]
