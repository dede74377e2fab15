"""Numba kernels of AMAT's sparse convolutions, shared by batch-1 inference (``batch1.fast_amat``) and the
training path's global conv + pool (``sparse_conv``).

The convolutions on the maps are linear, so they are split by input channel, and the maps are sparse. A
channel whose most common value is ``m`` contributes ``m * conv(ones)`` (:func:`ones_conv`, precomputed
per map size) plus the cells that differ from ``m``: a row's run of n equal cells adds ``value`` times a
precomputed run kernel (what n ones in a row add to each output row: one contiguous run of output cells
per kernel row; runs longer than :data:`RUN_MAX` in pieces). Channels where over half the cells differ
are convolved densely (:func:`conv_rows`). Exact for any input. The shared channels of the global map
(explored, occupied, target) are convolved once, for robot 0 (:func:`shared_base`); another robot adds
the convolution of the cells where its channels differ, or convolves its own when that is cheaper
(:func:`robot_conv`). Weights come in the layouts of :func:`conv_weights`; a kernel's ``w`` argument is
any namedtuple with its fields (:class:`ConvWeights`, or ``FastWeights`` of ``batch1.snapshot``).
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from catmip_rl.amat.kernels.numba_ops import copy, fill, kernel

__all__ = [
    "RUN_MAX",
    "ConvWeights",
    "conv_weights",
    "ones_conv",
    "add_planes",
    "shared_base",
    "robot_conv",
    "global_conv_all",
    "conv_rows",
    "max_pool",
]

_SHARED = 3  # global-map channels that robots with merged beliefs share: explored, occupied, target

RUN_MAX = 8
"""Longest run of equal cells with a precomputed run kernel; longer runs are added in pieces."""


@kernel
def _run_kernels(flipped, run_max):
    """(C, run_max, k, run_max + k - 1, O): per input channel and run length n, what n ones at input
    cells (r, c .. c + n - 1) add to output row r - k//2 + i at column c - k//2 + t:
    ``R[n - 1, i, t] = sum of the flipped kernel row i's taps j with 0 <= t - j < n`` (t < n + k - 1),
    built as R_n = R_(n-1) + the kernel row shifted by n - 1 (summed in float64)."""
    n_ch, k, _, n_out = flipped.shape
    out = np.zeros((n_ch, run_max, k, run_max + k - 1, n_out), np.float32)
    acc = np.empty((run_max + k - 1, n_out))
    for ch in range(n_ch):
        for i in range(k):
            acc[:] = 0.0
            for n in range(1, run_max + 1):
                for j in range(k):
                    for o in range(n_out):
                        acc[n - 1 + j, o] += flipped[ch, i, j, o]
                for t in range(n + k - 1):
                    for o in range(n_out):
                        out[ch, n - 1, i, t, o] = acc[t, o]
    return out


@kernel
def ones_conv(flipped, h, wd):
    """(C, H, W, O): per input channel, the convolution (no bias, zero padding) of an all-ones H x W
    plane with the flipped kernels (C, k, k, O): at each output cell, the sum of the taps that fall on
    the plane, from 2-D prefix sums of the kernel (float64)."""
    n_ch, k, _, n_out = flipped.shape
    pad = k // 2
    pre = np.zeros((k + 1, k + 1, n_out))
    out = np.empty((n_ch, h, wd, n_out), np.float32)
    for ch in range(n_ch):
        for i in range(k):
            for j in range(k):
                for o in range(n_out):
                    corner = pre[i, j + 1, o] + pre[i + 1, j, o] - pre[i, j, o]
                    pre[i + 1, j + 1, o] = corner + flipped[ch, i, j, o]
        for y in range(h):
            i0, i1 = min(k, max(0, y + pad - h + 1)), min(k, y + pad + 1)  # taps of output row y
            for x in range(wd):
                j0, j1 = min(k, max(0, x + pad - wd + 1)), min(k, x + pad + 1)
                for o in range(n_out):
                    out[ch, y, x, o] = pre[i1, j1, o] - pre[i0, j1, o] - pre[i1, j0, o] + pre[i0, j0, o]
    return out


ConvWeights = namedtuple("ConvWeights", ["g_w", "g_runs", "g_torch", "g_b"])
"""One k x k convolution in the layouts of the sparse convolution kernels (the global convolution's
fields of ``FastWeights``), for callers of the kernels such as ``sparse_conv``. Defined at module level:
numba's cache of the kernels compiled for it names the type."""


def conv_weights(weight: np.ndarray, bias: np.ndarray) -> ConvWeights:
    """A convolution (O, C, k, k) + bias (O,) in the kernels' layouts: flipped (C, k, k, O), its run
    kernels, torch's layout, the bias."""
    w = np.ascontiguousarray(weight, dtype=np.float32)
    flipped = np.ascontiguousarray(w[:, :, ::-1, ::-1].transpose(1, 2, 3, 0))
    b = np.ascontiguousarray(bias, dtype=np.float32)
    return ConvWeights(flipped, _run_kernels(flipped, RUN_MAX), w, b)


@kernel
def _add_run(out, runs_ch, r, c, n, v):
    """out (H, W, O) += the convolution of ``v`` at input cells (r, c .. c + n - 1), n <= RUN_MAX (zero
    padding), from the channel's run kernels runs_ch (RUN_MAX, k, RUN_MAX + k - 1, O): output row
    r - k//2 + i gains ``v * runs_ch[n - 1, i]`` over its valid columns, one contiguous run."""
    h, wd, n_out = out.shape
    k = runs_ch.shape[1]
    pad = k // 2
    t0, t1 = max(0, pad - c), min(n + k - 1, wd + pad - c)
    size = (t1 - t0) * n_out
    o_flat = out.ravel()
    for i in range(max(0, pad - r), min(k, h + pad - r)):
        o0 = ((r - pad + i) * wd + c - pad + t0) * n_out
        dst = o_flat[o0 : o0 + size]  # slices: indices provably >= 0, the loop vectorises
        src = runs_ch[n - 1, i].ravel()[t0 * n_out : t0 * n_out + size]
        for j in range(size):
            dst[j] += v * src[j]


@kernel
def _count_ne(x, y, ref):
    """Entries of the 1-D x - y that differ from ref (a loop that vectorises)."""
    cnt = 0
    for j in range(x.size):
        cnt += float(x[j]) - float(y[j]) != ref
    return cnt


@kernel
def _reference(flat, zero):
    """(m, cells that differ from m) of a flattened plane: m = its majority value if that beats 0, else 0."""
    nz = _count_ne(flat, zero, 0.0)
    if 2 * nz <= flat.size:
        return 0.0, nz
    cand, cnt = flat[0], 0  # Boyer-Moore majority vote
    for j in range(flat.size):
        if cnt == 0:
            cand, cnt = flat[j], 1
        elif flat[j] == cand:
            cnt += 1
        else:
            cnt -= 1
    other = _count_ne(flat, zero, float(cand))
    return (float(cand), other) if other < nz else (0.0, nz)


@kernel
def _add_runs(out, runs_ch, plane, under, ref, scale):
    """out (H, W, O) += conv of ``(plane - under - ref) * scale`` for one input channel: each row's runs
    of equal nonzero values through the run kernels (``RUN_MAX`` cells at a time)."""
    for r in range(plane.shape[0]):
        row, low = plane[r], under[r]
        if _count_ne(row, low, ref) == 0:  # sparse planes: most rows end here
            continue
        c = 0
        while c < row.size:
            v = float(row[c]) - float(low[c]) - ref
            e = c + 1
            if v != 0.0:
                while e < row.size and float(row[e]) - float(low[e]) - ref == v:
                    e += 1
                val = np.float32(v * scale)
                for start in range(c, e, RUN_MAX):
                    _add_run(out, runs_ch, r, start, min(RUN_MAX, e - start), val)
            c = e


@kernel
def _dense_conv(out, w_torch, planes, chans, scale):
    """out (H, W, O) += the convolution of ``planes[chans] * scale`` (zero padding), by ``conv_rows``
    on a padded channel-last copy; w_torch (O, C_in, k, k) is torch's layout."""
    h, wd, n_out = out.shape
    k, nd = w_torch.shape[2], chans.size
    pad, width = k // 2, (nd + 7) // 8 * 8  # zero channels up to a multiple of 8: whole vectors
    xp = np.zeros((h + 2 * pad, wd + 2 * pad, width), np.float32)
    w_sel = np.zeros((n_out, k, k * width), np.float32)
    for d in range(nd):
        for y in range(h):
            for x in range(wd):
                xp[y + pad, x + pad, d] = planes[chans[d], y, x] * scale
        for o in range(n_out):
            for ty in range(k):
                for tx in range(k):
                    w_sel[o, ty, tx * width + d] = w_torch[o, chans[d], ty, tx]
    res = np.empty((h * wd, n_out), np.float32)
    conv_rows(xp, w_sel, np.zeros(n_out, np.float32), res)
    o_flat, r_flat = out.ravel(), res.ravel()
    for j in range(o_flat.size):
        o_flat[j] += r_flat[j]


@kernel
def add_planes(out, conv, ones, planes, ch0, ch1, zero, scale):
    """out (H, W, O) += the convolution of input channels ch0 .. ch1-1 of ``planes * scale``.

    ``conv`` = (run kernels (C_in, RUN_MAX, k, RUN_MAX + k - 1, O), torch's (O, C_in, k, k)).
    A channel contributes ``m * conv(ones)`` for its majority value m (if any), then the runs of cells
    that differ from m; channels where over half the cells differ are convolved densely, together.
    """
    runs, w_torch = conv
    dense = np.empty(ch1 - ch0, np.int64)
    n_dense = 0
    for ch in range(ch0, ch1):
        ref, cost = _reference(planes[ch].ravel(), zero.ravel())
        if 2 * cost > zero.size:
            dense[n_dense] = ch
            n_dense += 1
            continue
        if ref != 0.0:
            m = np.float32(ref * scale)
            o_flat, ones_flat = out.ravel(), ones[ch].ravel()
            for j in range(o_flat.size):
                o_flat[j] += m * ones_flat[j]
        _add_runs(out, runs[ch], planes[ch], zero, ref, scale)
    if n_dense:
        _dense_conv(out, w_torch, planes, dense[:n_dense], scale)


@kernel
def shared_base(w, gmap, scale, ones, zero, base):
    """base (S, S, O) = bias + robot 0's convolution of the shared channels (explored, occupied, target)."""
    fill(base, w.g_b)
    add_planes(base, (w.g_runs, w.g_torch), ones, gmap[0], 0, min(_SHARED, gmap.shape[1]), zero, scale)
    return base


@kernel
def robot_conv(w, gmap, i, scale, ones, zero, base, out):
    """out (S, S, O) = robot i's global convolution. Its shared channels start from robot 0's (``base``)
    plus the convolution of the cells where they differ, unless computing them afresh is cheaper."""
    shared = min(_SHARED, gmap.shape[1])
    conv = (w.g_runs, w.g_torch)
    diff = 0
    for ch in range(shared):
        diff += _count_ne(gmap[i, ch].ravel(), gmap[0, ch].ravel(), 0.0)
    own = 0
    if diff:
        for ch in range(shared):
            own += min(_reference(gmap[i, ch].ravel(), zero.ravel())[1], zero.size // 2)
    if diff <= own:
        copy(out, base)
        if diff:
            for ch in range(shared):
                _add_runs(out, w.g_runs[ch], gmap[i, ch], gmap[0, ch], 0.0, scale)
        first = shared
    else:
        fill(out, w.g_b)
        first = 0
    add_planes(out, conv, ones, gmap[i], first, gmap.shape[1], zero, scale)


@kernel
def global_conv_all(w, gmap, scale, ones):
    """(N, S, S, O): every robot's global convolution (channel-last)."""
    zero = np.zeros(gmap.shape[2:], gmap.dtype)
    base = shared_base(w, gmap, scale, ones, zero, np.empty(gmap.shape[2:] + (w.g_b.size,), np.float32))
    out = np.empty((gmap.shape[0], gmap.shape[2], gmap.shape[3], w.g_b.size), np.float32)
    for i in range(gmap.shape[0]):
        robot_conv(w, gmap, i, scale, ones, zero, base, out[i])
    return out


@kernel
def conv_rows(xp, w, b, out):
    """out (H*W, O) = b + the k x k convolution of the padded xp (H+k-1, W+k-1, C) with w (O, k, k*C)
    in (o, ty, (tx, c)) order: each kernel row reads a contiguous run of xp; tiles of 2 pixels x 4
    outputs."""
    hp, wp, c = xp.shape
    n_out, k, run = w.shape
    wd = wp - k + 1
    n_pix = (hp - k + 1) * wd
    flat = xp.ravel()
    for o in range(0, n_out, 4):
        o1, o2, o3 = min(o + 1, n_out - 1), min(o + 2, n_out - 1), min(o + 3, n_out - 1)
        for p in range(0, n_pix, 2):
            q = min(p + 1, n_pix - 1)
            a0 = a1 = a2 = a3 = c0 = c1 = c2 = c3 = np.float32(0.0)
            for ty in range(k):
                sp, sq = ((p // wd + ty) * wp + p % wd) * c, ((q // wd + ty) * wp + q % wd) * c
                x0, x1 = flat[sp : sp + run], flat[sq : sq + run]
                w0, w1, w2, w3 = w[o, ty], w[o1, ty], w[o2, ty], w[o3, ty]
                for j in range(run):
                    u, v = x0[j], x1[j]
                    p0, p1, p2, p3 = w0[j], w1[j], w2[j], w3[j]
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
                    out[p, o + j] = sa + b[o + j]
                    out[q, o + j] = sc + b[o + j]


@kernel
def max_pool(x, g, out):
    """Adaptive max pool of x (S, S, O) to out (O * g * g,) in (o, gy, gx) order (torch's bins)."""
    h, wd, n_out = x.shape
    x_flat = x.ravel()
    row = wd * n_out
    col_max = np.empty(row, np.float32)
    for gy in range(g):
        y0, y1 = gy * h // g, ((gy + 1) * h + g - 1) // g
        copy(col_max, x_flat[y0 * row : (y0 + 1) * row])
        for y in range(y0 + 1, y1):
            src = x_flat[y * row : (y + 1) * row]  # a slice, so that the loop vectorises
            for j in range(row):
                col_max[j] = np.maximum(col_max[j], src[j])
        for gx in range(g):
            x0, x1 = gx * wd // g, ((gx + 1) * wd + g - 1) // g
            best = col_max[x0 * n_out : (x0 + 1) * n_out].copy()
            for xx in range(x0 + 1, x1):
                src = col_max[xx * n_out : (xx + 1) * n_out]
                for o in range(n_out):
                    best[o] = np.maximum(best[o], src[o])
            for o in range(n_out):
                out[(o * g + gy) * g + gx] = best[o]
