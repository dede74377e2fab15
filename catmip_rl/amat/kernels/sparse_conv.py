"""The global CNN of AMAT's embedder for training on CPU: convolution + adaptive max pool, forward and
backward, on the sparse uint8 global maps (docs/design.md#observations, #amat).

``global_conv_pool(gmap, weight, bias, pool)`` equals
``adaptive_max_pool2d(conv2d(gmap * 0.25, weight, bias, padding=k // 2), pool)`` with its gradients for
``weight`` and ``bias`` (the maps are data: no input gradient), at a fraction of the dense cost:

* forward — per decision event, the robots' global convolutions by the shared/sparse split of
  ``kernels.conv`` (the belief channels that merged robots share are convolved once, the robot stamps
  and goal as the few cells they are; exact for any input, dense where that is cheaper), then the max
  pool, keeping the winning cell of every (robot, channel, bin);
* backward — max pooling passes each bin's gradient to its winning cell alone, so the weight gradient
  is ``sum over (robot, channel, bin) of grad * (the k x k input patch at the winning cell)``: one
  contiguous run per patch in a copy of the map laid out by kernel column, four bins of a channel at a
  time, instead of a dense correlation over every cell.

Both are numba loops (GIL released) over a fixed number of chunks of the batch, run on torch's number of
threads: the results do not depend on the thread count. Ties inside a bin go to the first cell in
row-major order, as torch's pool; because the sums run in another order than torch's convolution, a
near-tie can pick another cell than the dense path would (values agree to float32 rounding either way).

The convolution kernels are ``kernels.conv``' (shared with ``FastAmat``); this module adds the pool that
remembers its winners, the weight gradient, the thread-pool chunking and the autograd ``Function``.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import torch
from numba import njit

from catmip_env.constants import OBS_SCALE
from catmip_rl.amat.kernels.conv import conv_weights, ones_conv, robot_conv, shared_base

__all__ = ["global_conv_pool", "global_conv_pool_winners", "GlobalConvPool", "CHUNKS"]

CHUNKS = 8
"""Work split of the parallel loops: fixed, so that results do not depend on the thread count."""

_jit = njit(cache=True, nogil=True, error_model="numpy", fastmath={"reassoc", "contract", "nsz"})


@_jit
def _pool_argmax(x, g, pooled, where):
    """Adaptive max pool of x (S, S, O) into pooled (O, g, g) and the winning flat cell y * S + x into
    where (O, g, g); torch's bins, the first maximum in row-major order (strictly greater replaces).

    The running maximum and its cell alternate between two buffers, read from one and written to the
    other: an in-place ``best = v if v > best else best`` compiles to masked vector stores, which cost
    this loop 2x on AMD CPUs."""
    h, wd, n_out = x.shape
    flat = x.ravel()
    best, best_next = np.empty(n_out, np.float32), np.empty(n_out, np.float32)
    arg, arg_next = np.empty(n_out, np.int32), np.empty(n_out, np.int32)
    for gy in range(g):
        y0, y1 = gy * h // g, ((gy + 1) * h + g - 1) // g
        for gx in range(g):
            x0, x1 = gx * wd // g, ((gx + 1) * wd + g - 1) // g
            first = y0 * wd + x0
            best[:] = flat[first * n_out : (first + 1) * n_out]
            arg[:] = first
            for yy in range(y0, y1):
                for xx in range(x0 + (yy == y0), x1):
                    cell = np.int32(yy * wd + xx)
                    row = flat[cell * n_out : (cell + 1) * n_out]  # a slice: the loop vectorises
                    for o in range(n_out):
                        v, b = row[o], best[o]
                        gt = v > b
                        best_next[o] = v if gt else b
                        arg_next[o] = cell if gt else arg[o]
                    best, best_next, arg, arg_next = best_next, best, arg_next, arg
            for o in range(n_out):
                pooled[o, gy, gx] = best[o]
                where[o, gy, gx] = arg[o]


@_jit
def _forward(w, gmap, scale, ones, g, pooled, where, m0, m1):
    """Events m0 .. m1-1 of gmap (M, N, C, S, S): pooled and where (M * N, O, g, g) of their robots
    (``kernels.conv``' shared base + per-robot convolution, into buffers reused across events)."""
    n, _, h, wd = gmap.shape[1:]
    zero = np.zeros((h, wd), gmap.dtype)
    base = np.empty((h, wd, w.g_b.size), np.float32)
    work = np.empty((h, wd, w.g_b.size), np.float32)
    for m in range(m0, m1):
        shared_base(w, gmap[m], scale, ones, zero, base)
        for i in range(n):
            robot_conv(w, gmap[m], i, scale, ones, zero, base, work)
            _pool_argmax(work, g, pooled[m * n + i], where[m * n + i])


@_jit
def _weight_grad(  # noqa: C901 - numba kernel: one tuned, vectorised loop nest (backward hot path)
    gmap, scale, grad, where, k, r0, r1, acc
):
    """acc (O, k (ty), k (tx), 8) += the weight gradient of robots r0 .. r1-1: grad * the input patch at
    each bin's winning cell, summed. gmap (R, C, S, S) uint8 / float, grad and where (R, O, g, g).

    The map is copied zero-padded, channel-last with the channels padded to 8, and stacked by kernel
    column: ``cols[x, y] = padded[y, x : x + k]`` (k * 8 floats). The patch of output cell (y, x) is then
    one contiguous run ``cols[x, y : y + k]`` of k * k * 8 floats, and the copy is one contiguous run per
    (x, y) too. The bins of one output channel share their destination, so they are added four at a
    time (one load and store of it for four products)."""
    n_ch, h, wd = gmap.shape[1:]
    n_out, ch8 = acc.shape[0], acc.shape[3]
    pad = k // 2
    hp, wp = h + 2 * pad, wd + 2 * pad
    seg = k * ch8  # one kernel row of a patch
    run = k * seg
    padded = np.zeros((hp, wp, ch8), np.float32)  # borders and channels >= C stay 0
    cols = np.empty((wd, hp, k, ch8), np.float32)
    a, v, p = acc.ravel(), cols.ravel(), padded.ravel()
    gains = np.zeros(grad[0, 0].size + 3, np.float32)  # one channel's nonzero bins, padded to 4s
    starts = np.zeros(grad[0, 0].size + 3, np.int64)
    for r in range(r0, r1):
        for c in range(n_ch):
            for y in range(h):
                for x in range(wd):
                    padded[y + pad, x + pad, c] = gmap[r, c, y, x] * scale
        for x in range(wd):
            for y in range(hp):
                d0, s0 = (x * hp + y) * seg, (y * wp + x) * ch8
                dst, src = v[d0 : d0 + seg], p[s0 : s0 + seg]
                for q in range(seg):
                    dst[q] = src[q]
        for o in range(n_out):
            gr, wr = grad[r, o].ravel(), where[r, o].ravel()
            used = 0
            for j in range(gr.size):
                if gr[j] != 0.0:
                    gains[used] = gr[j]
                    starts[used] = ((wr[j] % wd) * hp + wr[j] // wd) * seg
                    used += 1
            for j in range(used, (used + 3) // 4 * 4):
                gains[j], starts[j] = 0.0, 0
            dst = a[o * run : (o + 1) * run]
            for j in range(0, used, 4):
                g0, g1, g2, g3 = gains[j], gains[j + 1], gains[j + 2], gains[j + 3]
                s0 = v[starts[j] : starts[j] + run]  # slices, so that the loop vectorises
                s1 = v[starts[j + 1] : starts[j + 1] + run]
                s2 = v[starts[j + 2] : starts[j + 2] + run]
                s3 = v[starts[j + 3] : starts[j + 3] + run]
                for q in range(run):
                    dst[q] += g0 * s0[q] + g1 * s1[q] + g2 * s2[q] + g3 * s3[q]


_POOLS: dict[int, ThreadPoolExecutor] = {}


def _in_chunks(work: Callable[[int, int, int], None], n_items: int) -> None:
    """``work(lo, hi, chunk)`` on CHUNKS contiguous ranges of ``n_items``, on as many threads as torch
    uses (the kernels release the GIL; no second OpenMP runtime next to torch's)."""
    bounds = np.linspace(0, n_items, CHUNKS + 1).astype(np.int64)
    jobs = [(int(bounds[c]), int(bounds[c + 1]), c) for c in range(CHUNKS) if bounds[c + 1] > bounds[c]]
    workers = max(1, min(torch.get_num_threads(), len(jobs)))
    if workers == 1:
        for job in jobs:
            work(*job)
        return
    if workers not in _POOLS:
        _POOLS[workers] = ThreadPoolExecutor(workers, thread_name_prefix="catmip-sparse-conv")
    for future in [_POOLS[workers].submit(work, *job) for job in jobs]:
        future.result()


def _conv_pool(gmap: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor, pool: int):
    m, n, _, s, s2 = gmap.shape
    n_out = weight.shape[0]
    weights = conv_weights(weight.detach().float().cpu().numpy(), bias.detach().float().cpu().numpy())
    ones = ones_conv(weights.g_w, s, s2)
    maps = gmap.numpy()
    pooled = np.empty((m * n, n_out, pool, pool), np.float32)
    where = np.empty((m * n, n_out, pool, pool), np.int32)
    scale = np.float32(OBS_SCALE)
    _in_chunks(lambda lo, hi, _: _forward(weights, maps, scale, ones, pool, pooled, where, lo, hi), m)
    return pooled, where


class GlobalConvPool(torch.autograd.Function):
    """``(gmap (M, N, C, S, S) uint8, weight, bias, pool) -> (M * N, O, pool, pool)``; see the module."""

    @staticmethod
    def forward(ctx, gmap: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor, pool: int) -> torch.Tensor:
        """The pooled convolution; keeps where each pooled maximum came from for the backward pass."""
        pooled, where = _conv_pool(gmap, weight, bias, pool)
        ctx.save_for_backward(gmap)
        ctx.where, ctx.k = where, weight.shape[-1]
        return torch.from_numpy(pooled)

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        """Gradients of the weight and bias (the map is data: none for it, nor for ``pool``)."""
        (gmap,) = ctx.saved_tensors
        d_weight = d_bias = None
        if ctx.needs_input_grad[1]:
            g = np.ascontiguousarray(grad.detach().float().numpy())
            maps = gmap.flatten(0, 1).numpy()
            n_out, n_ch, k = g.shape[1], maps.shape[1], ctx.k
            acc = np.zeros((CHUNKS, n_out, k, k, (n_ch + 7) // 8 * 8), np.float32)  # one per chunk
            scale = np.float32(OBS_SCALE)
            where = ctx.where
            _in_chunks(lambda lo, hi, c: _weight_grad(maps, scale, g, where, k, lo, hi, acc[c]), len(maps))
            total = acc.sum(0, dtype=np.float64)[..., :n_ch].transpose(0, 3, 1, 2)  # (O, C, ty, tx)
            d_weight = torch.from_numpy(np.ascontiguousarray(total, dtype=np.float32))
        if ctx.needs_input_grad[2]:
            d_bias = grad.sum((0, 2, 3))
        return None, d_weight, d_bias, None


def global_conv_pool(gmap: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor, pool: int) -> torch.Tensor:
    """Global conv + adaptive max pool of uint8 maps (M, N, C, S, S) on CPU -> (M * N, O, pool, pool)."""
    _check(gmap, weight)
    return GlobalConvPool.apply(gmap.contiguous(), weight, bias, pool)


def _check(gmap: torch.Tensor, weight: torch.Tensor) -> None:
    if gmap.dtype != torch.uint8 or gmap.dim() != 5 or gmap.device.type != "cpu":
        raise ValueError(
            f"global_conv_pool needs CPU uint8 maps (M, N, C, S, S), got {gmap.dtype} {tuple(gmap.shape)} "
            f"on {gmap.device}"
        )
    if gmap.shape[2] != weight.shape[1] or gmap.shape[3] != gmap.shape[4]:
        raise ValueError(
            f"maps must be (M, N, {weight.shape[1]}, S, S) for this convolution, got {tuple(gmap.shape)}"
        )


def global_conv_pool_winners(
    gmap: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor, pool: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """The forward of :func:`global_conv_pool` without autograd, and the winning cell ``y * S + x`` of
    every (robot, channel, bin) that its backward passes the gradient to: ``(M * N, O, pool, pool)``
    float32 and int64. A bin whose best cells tie up to float32 rounding may pick another of them than
    a dense float32 convolution does (the sums run in another order)."""
    _check(gmap, weight)
    with torch.no_grad():
        pooled, where = _conv_pool(gmap.contiguous(), weight, bias, pool)
    return torch.from_numpy(pooled), torch.from_numpy(where).long()
