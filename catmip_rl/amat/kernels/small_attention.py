"""Attention over the few tokens of a decision event, for training on CPU (docs/design.md#amat).

AMAT attends over one event's robots: sequences of N <= 12 tokens. ``scaled_dot_product_attention`` on
CPU spends ~1 ms forward and ~2 ms backward per call on a 256-event Task-2 batch (N = 3, d = 192) in
kernels tiled for long sequences, while the arithmetic is ~1 M multiply-adds. ``small_attention`` does
the same computation in plain numba loops over events, heads and token pairs (each a vectorised loop
over the head's channels): the same result to float32 rounding, gradients for query, key and value,
in a fraction of the time.

``small_attention(q, k, v, allowed, n_heads)``: q (B, Tq, d), k and v (B, Tk, d), head h on channels
h * d / n_heads .. (h + 1) * d / n_heads - 1 (the layout of ``Attention.split``); ``allowed``
broadcastable to (B, 1, Tq, Tk), True = may attend, or None. Softmax(q k^T / sqrt(d / n_heads)) v per
head. A query that may attend to no key gets zeros (scaled_dot_product_attention gives NaN there).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit

__all__ = ["small_attention", "SmallAttention"]

_jit = njit(cache=True, nogil=True, error_model="numpy", fastmath={"reassoc", "contract", "nsz"})


@_jit
def _forward(q, k, v, allowed, n_heads, scale, y, p):
    """y (B, Tq, d) and the attention weights p (B, heads, Tq, Tk)."""
    b, tq, d = q.shape
    tk = k.shape[1]
    dh = d // n_heads
    for e in range(b):
        for h in range(n_heads):
            lo, hi = h * dh, (h + 1) * dh
            for i in range(tq):
                qi, pi, yi = q[e, i, lo:hi], p[e, h, i], y[e, i, lo:hi]
                top = -np.inf
                for j in range(tk):
                    if allowed[e, i, j]:
                        kj = k[e, j, lo:hi]
                        s = 0.0
                        for c in range(dh):
                            s += qi[c] * kj[c]
                        pi[j] = s * scale
                        top = max(top, pi[j])
                total = 0.0
                for j in range(tk):
                    pi[j] = math.exp(pi[j] - top) if allowed[e, i, j] else 0.0
                    total += pi[j]
                inv = 1.0 / total if total > 0.0 else 0.0
                yi[:] = 0.0
                for j in range(tk):
                    pi[j] *= inv
                    if pi[j] != 0.0:
                        pj, vj = pi[j], v[e, j, lo:hi]
                        for c in range(dh):
                            yi[c] += pj * vj[c]


@_jit
def _backward(q, k, v, p, gy, n_heads, scale, gq, gk, gv):
    """Gradients of the inputs from the output's gradient gy (B, Tq, d) and the saved weights p."""
    b, tq, d = q.shape
    tk = k.shape[1]
    dh = d // n_heads
    gk[:] = 0.0
    gv[:] = 0.0
    gp = np.empty(tk, p.dtype)
    for e in range(b):
        for h in range(n_heads):
            lo, hi = h * dh, (h + 1) * dh
            for i in range(tq):
                pi, gyi, qi, gqi = p[e, h, i], gy[e, i, lo:hi], q[e, i, lo:hi], gq[e, i, lo:hi]
                mean = 0.0  # sum_j p_ij * dL/dp_ij
                for j in range(tk):
                    gp[j] = 0.0
                    if pi[j] != 0.0:
                        vj = v[e, j, lo:hi]
                        s = 0.0
                        for c in range(dh):
                            s += gyi[c] * vj[c]
                        gp[j] = s
                        mean += pi[j] * s
                gqi[:] = 0.0
                for j in range(tk):
                    if pi[j] == 0.0:
                        continue
                    pj, gs = pi[j], pi[j] * (gp[j] - mean) * scale  # dL/d(score) times the scale
                    kj, gkj, gvj = k[e, j, lo:hi], gk[e, j, lo:hi], gv[e, j, lo:hi]
                    for c in range(dh):
                        gvj[c] += pj * gyi[c]
                        gqi[c] += gs * kj[c]
                        gkj[c] += gs * qi[c]


def _numpy(x: torch.Tensor) -> np.ndarray:
    return x.detach().contiguous().numpy()


class SmallAttention(torch.autograd.Function):
    """``(q, k, v, allowed (B, Tq, Tk) bool, n_heads) -> (B, Tq, d)``; see the module docstring."""

    @staticmethod
    def forward(ctx, q, k, v, allowed, n_heads):
        """The attention output (B, Tq, d); keeps the attention weights for the backward pass."""
        b, tq, d = q.shape
        qn, kn, vn = _numpy(q), _numpy(k), _numpy(v)
        y = np.empty((b, tq, d), qn.dtype)
        p = np.empty((b, n_heads, tq, k.shape[1]), qn.dtype)
        scale = qn.dtype.type(1.0 / math.sqrt(d // n_heads))
        _forward(qn, kn, vn, allowed.numpy(), n_heads, scale, y, p)
        ctx.saved = (qn, kn, vn, p, n_heads, scale)
        return torch.from_numpy(y)

    @staticmethod
    def backward(ctx, grad):
        """Gradients of q, k and v from the output's (none for ``allowed`` and ``n_heads``)."""
        qn, kn, vn, p, n_heads, scale = ctx.saved
        gq, gk, gv = np.empty_like(qn), np.empty_like(kn), np.empty_like(vn)
        _backward(qn, kn, vn, p, _numpy(grad), n_heads, scale, gq, gk, gv)
        return torch.from_numpy(gq), torch.from_numpy(gk), torch.from_numpy(gv), None, None


def small_attention(
    q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, allowed: torch.Tensor | None, n_heads: int
) -> torch.Tensor:
    """Multi-head attention of CPU float tensors q (B, Tq, d) over k, v (B, Tk, d) -> (B, Tq, d)."""
    if q.device.type != "cpu" or not (q.dtype == k.dtype == v.dtype) or not q.dtype.is_floating_point:
        raise ValueError(f"small_attention needs CPU float tensors of one dtype, got {q.dtype} on {q.device}")
    b, tq, d = q.shape
    if k.shape != v.shape or k.shape[0] != b or k.shape[2] != d or d % n_heads:
        raise ValueError(
            f"small_attention: q {tuple(q.shape)}, k {tuple(k.shape)}, v {tuple(v.shape)} do not fit "
            f"(B, Tq, d), (B, Tk, d), (B, Tk, d) with d divisible by n_heads = {n_heads}"
        )
    tk = k.shape[1]
    if allowed is None:
        allowed = torch.ones(1, 1, 1, 1, dtype=torch.bool)
    allowed = allowed.to(torch.bool).expand(b, 1, tq, tk)[:, 0].contiguous()
    return SmallAttention.apply(q, k, v, allowed, n_heads)
