"""Small numba kernels of :class:`~catmip_rl.amat.onboard.fast_amat.FastAmat` on float32 vectors and
matrices: matrix products in register tiles, LayerNorm, exact GELU, one query's softmax attention,
class tokens.

Every FastAmat kernel (here, in ``kernels.conv`` and in ``batch1.fast_amat``) is compiled by the one decorator
:data:`kernel`, so they all share its options; numba resolves a kernel's calls to kernels of other
modules at compile time and compiles them into the caller (numba's on-disk cache would not see those
callees change; ``catmip_env.runtime.numba_cache`` drops the package's caches when its sources change).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = [
    "kernel",
    "LN_EPS",
    "matvec",
    "linear",
    "layer_norm",
    "dot",
    "fill",
    "relu",
    "copy",
    "gelu",
    "add_ln",
    "attend",
    "one_hot",
    "class_token",
]

kernel = njit(cache=True, error_model="numpy", fastmath={"reassoc", "contract", "nsz"})
"""The decorator of every FastAmat kernel. Reassociation lets LLVM vectorise reductions (no finite-math
assumptions: -1e10 logits, -inf maxima); numpy's error model drops the ZeroDivisionError branches that
would stop loops from vectorising."""

LN_EPS = 1e-5
"""torch's LayerNorm default, used by every AMAT LayerNorm."""


@kernel
def matvec(x, w, b, out):
    """out (O,) = w (O, K) @ x (K,) + b, four outputs per pass over x."""
    n_out, k_in = w.shape
    for o in range(0, n_out, 4):
        w0, w1, w2, w3 = w[o], w[min(o + 1, n_out - 1)], w[min(o + 2, n_out - 1)], w[min(o + 3, n_out - 1)]
        s0 = s1 = s2 = s3 = np.float32(0.0)
        for k in range(k_in):
            xk = x[k]
            s0 += xk * w0[k]
            s1 += xk * w1[k]
            s2 += xk * w2[k]
            s3 += xk * w3[k]
        for j, sj in enumerate((s0, s1, s2, s3)):
            if o + j < n_out:
                out[o + j] = sj + b[o + j]


@kernel
def linear(x, w, b, out):
    """out (M, O) = x (M, K) @ w (O, K).T + b, in tiles of 2 rows x 4 outputs (eight accumulators);
    each group of 4 weight rows is read once (from L1) for all the rows of x."""
    m_rows, k_in = x.shape
    n_out = w.shape[0]
    for o in range(0, n_out, 4):
        w0, w1, w2, w3 = w[o], w[min(o + 1, n_out - 1)], w[min(o + 2, n_out - 1)], w[min(o + 3, n_out - 1)]
        for m in range(0, m_rows, 2):
            m1 = min(m + 1, m_rows - 1)
            x0, x1 = x[m], x[m1]
            a0 = a1 = a2 = a3 = c0 = c1 = c2 = c3 = np.float32(0.0)
            for k in range(k_in):
                u, v = x0[k], x1[k]
                p0, p1, p2, p3 = w0[k], w1[k], w2[k], w3[k]
                a0 += u * p0
                a1 += u * p1
                a2 += u * p2
                a3 += u * p3
                c0 += v * p0
                c1 += v * p1
                c2 += v * p2
                c3 += v * p3
            for j, (sa, sc) in enumerate(((a0, c0), (a1, c1), (a2, c2), (a3, c3))):
                if o + j < n_out:
                    out[m, o + j] = sa + b[o + j]
                    out[m1, o + j] = sc + b[o + j]


@kernel
def layer_norm(x, wb, out):
    """out = LayerNorm(x) over all of x (1-D), affine ``wb`` (2, n); out may be x."""
    n = x.size
    s = 0.0
    for j in range(n):
        s += x[j]
    mean = s / n
    v = 0.0
    for j in range(n):
        dv = x[j] - mean
        v += dv * dv
    mean32, inv32 = np.float32(mean), np.float32(1.0 / math.sqrt(v / n + LN_EPS))
    for j in range(n):
        out[j] = (x[j] - mean32) * inv32 * wb[0, j] + wb[1, j]


@kernel
def dot(x, y):
    s = np.float32(0.0)
    for j in range(x.size):
        s += x[j] * y[j]
    return s


@kernel
def fill(out, b):
    """out (H, W, O)[y, x] = b (O,) everywhere."""
    for y in range(out.shape[0]):
        for x in range(out.shape[1]):
            out[y, x] = b


@kernel
def relu(x):
    for j in range(x.size):
        x[j] = np.maximum(x[j], np.float32(0.0))  # np.maximum vectorises, max() does not


@kernel
def copy(out, x):
    """out[:] = x for equal-shape C-contiguous arrays (a flat loop that vectorises)."""
    o_flat, x_flat = out.ravel(), x.ravel()
    for j in range(o_flat.size):
        o_flat[j] = x_flat[j]


# erf(z) ~ z P(z^2) / Q(z^2) on [-4, 4] (Eigen's single-precision rational; in float64 the error is
# below 7e-8, less than torch's own float32 erf): branch-free, so the GELU loop vectorises.
_ERF_P = (
    -1.60960333262415e-02,
    -2.95459980854025e-03,
    -7.34990630326855e-04,
    -5.69250639462346e-05,
    -2.10102402082508e-06,
    2.77068142495902e-08,
    -2.72614225801306e-10,
)
_ERF_Q = (
    -1.42647390514189e-02,
    -7.37332916720468e-03,
    -1.68282697438203e-03,
    -2.13374055278905e-04,
    -1.45660718464996e-05,
)


@kernel
def gelu(x):
    """In place, the exact (erf) form of ``F.gelu``."""
    p0, p1, p2, p3, p4, p5, p6 = _ERF_P
    q0, q1, q2, q3, q4 = _ERF_Q
    for j in range(x.size):
        v = float(x[j])
        z = np.minimum(np.maximum(v * 0.7071067811865476, -4.0), 4.0)
        z2 = z * z
        num = z * (p0 + z2 * (p1 + z2 * (p2 + z2 * (p3 + z2 * (p4 + z2 * (p5 + z2 * p6))))))
        den = q0 + z2 * (q1 + z2 * (q2 + z2 * (q3 + z2 * q4)))
        x[j] = 0.5 * v * (1.0 + num / den)


@kernel
def add_ln(x, y, wb, out):
    """out = LayerNorm(x + y); out may be x or y."""
    for j in range(x.size):
        out[j] = x[j] + y[j]
    layer_norm(out, wb, out)


@kernel
def attend(q, keys, values, t, n_heads, scores, out):
    """Softmax attention of one query (d,) over the first t rows of keys / values (T, d), per head."""
    dh = q.size // n_heads
    scale = 1.0 / math.sqrt(dh)
    for h in range(n_heads):
        lo, hi = h * dh, (h + 1) * dh
        qh, oh = q[lo:hi], out[lo:hi]
        top = -np.inf
        for j in range(t):
            scores[j] = dot(qh, keys[j, lo:hi]) * scale
            top = max(top, scores[j])
        total = 0.0
        for j in range(t):
            scores[j] = math.exp(scores[j] - top)
            total += scores[j]
        oh[:] = 0.0
        for j in range(t):
            p = np.float32(scores[j] / total)
            vh = values[j, lo:hi]
            for c in range(dh):
                oh[c] += p * vh[c]


@kernel
def one_hot(c):
    """Index of the 1 if c is exactly one-hot, else -1."""
    hot = -1
    for j in range(c.size):
        if c[j] == 1.0 and hot < 0:
            hot = j
        elif c[j] != 0.0:
            return -1
    return hot


@kernel
def class_token(c, tab, w, b, out):
    """GELU(Linear(c)) (d,): a table row for a one-hot c, else computed."""
    hot = one_hot(c)
    if hot >= 0:
        out[:] = tab[hot]
    else:
        matvec(c, w, b, out)
        gelu(out)
