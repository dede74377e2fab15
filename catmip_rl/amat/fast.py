"""Fast batch-1 AMAT decisions on CPU: numba kernels over weights snapshotted from an :class:`AMAT`.

>>> fast = FastAmat.from_model(model)     # copies the weights: rebuild it after the model changes
>>> actions, log_probs, values = fast.decide(global_map, local_map, agent_class, action_mask, active)

One world (no batch axis): embed every robot, encode, decode the active robots autoregressively, as
``model.embed`` -> ``model.encode`` -> ``model.decode_autoregressive`` (same argmax actions; log-probs and
values equal to float32 rounding), in one numba call, without torch. What makes it fast:

* the convolutions on the maps are linear, so they are split by input channel, and the maps are
  sparse. A channel whose most common value is ``m`` contributes ``m * conv(ones)`` (precomputed per
  map size) plus the cells that differ from ``m``: a row's run of n equal cells adds ``value`` times
  a precomputed run kernel (what n ones in a row add to each output row: one contiguous run of output
  cells per kernel row; runs longer than ``RUN_MAX`` in pieces). Channels where over half the cells
  differ are convolved densely. Exact for any input;
* the shared channels of the global map (explored, occupied, target) are convolved once, for robot 0;
  another robot adds the convolution of the cells where its channels differ (none under merged
  beliefs: compared, never assumed), or convolves its own when that is cheaper;
* d-sized matrix products in register tiles; the decoder's first-block input and q/k/v projections,
  which depend only on (class, previous action), are tabulated; exact GELU by a branch-free rational
  erf (error below 1e-7).
"""

from __future__ import annotations

import math
from collections import namedtuple
from collections.abc import Mapping
from typing import Any

import numpy as np
from numba import njit

from catmip_rl.amat.model import INVALID_LOGIT, OBS_SCALE, AmatConfig

__all__ = ["FastAmat"]

# reassociation lets LLVM vectorise reductions (no finite-math assumptions: -1e10 logits, -inf maxima);
# numpy's error model drops the ZeroDivisionError branches that would stop loops from vectorising.
_jit = njit(cache=True, error_model="numpy", fastmath={"reassoc", "contract", "nsz"})
_LN_EPS = 1e-5  # torch's LayerNorm default, used by every AMAT LayerNorm
_SHARED = 3  # global-map channels that robots with merged beliefs share: explored, occupied, target

_Weights = namedtuple(
    "_Weights",
    [
        # embedder: convolutions in scatter layout (in, flipped ky, flipped kx, out), with run kernels
        # and a dense layout; LayerNorms as (2, n) = weight, bias; local activations channel-last
        "g_w", "g_runs", "g_torch", "g_b", "g_ln", "l1_w", "l1_runs", "l1_torch", "l1_b", "l1_ln",
        "l2_w", "l2_b", "l2_ln",
        "fc1_w", "fc1_b", "obs_ln", "fc2_w", "fc2_b", "cls_w", "cls_b", "cls_tab",
        # encoder (per-block tensors stacked along axis 0) and value head
        "enc_ln", "e_qkv_w", "e_qkv_b", "e_out_w", "e_out_b", "e_ln1",
        "e_fc1_w", "e_fc1_b", "e_fc2_w", "e_fc2_b", "e_ln2", "v_w1", "v_b1", "v_ln", "v_w2", "v_b2",
        # macro-action embedder, decoder, policy head
        "act_tab", "dcls_w", "dcls_b", "dcls_tab", "dec_ln", "dx_tab", "dqkv_tab",
        "d_qkv_w", "d_qkv_b", "d_sout_w", "d_sout_b", "d_ln1", "d_q_w", "d_q_b", "d_kv_w", "d_kv_b",
        "d_cout_w", "d_cout_b", "d_ln2", "d_fc1_w", "d_fc1_b", "d_fc2_w", "d_fc2_b", "d_ln3",
        "h_w1", "h_b1", "h_ln", "h_w2", "h_b2",
    ],
)  # fmt: skip


class FastAmat:
    """Batch-1 AMAT inference (embed, encode, autoregressive decode) in numba.

    The weights are copied at construction: build a new object after the model's weights change.

    Parameters
    ----------
    config : AmatConfig
        The model's configuration.
    state_dict : Mapping
        ``AMAT.state_dict()`` (torch tensors or numpy arrays).
    """

    def __init__(self, config: AmatConfig, state_dict: Mapping[str, Any]) -> None:
        self.config = config
        self._w = _extract(config, {k: _numpy(v) for k, v in state_dict.items()})
        self._ones_local = ones_conv(self._w.l1_w, config.local_size, config.local_size)
        self._ones_global: dict[int, np.ndarray] = {}

    @classmethod
    def from_model(cls, model: Any) -> FastAmat:
        """Snapshot of an ``AMAT`` module's current weights."""
        return cls(model.config, model.state_dict())

    # -- public API -------------------------------------------------------------------------------
    def decide(
        self,
        global_map: np.ndarray,
        local_map: np.ndarray,
        agent_class: np.ndarray,
        action_mask: np.ndarray,
        active: np.ndarray,
        deterministic: bool = True,
        rng: np.random.Generator | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One decision of one world.

        Parameters
        ----------
        global_map, local_map : ndarray
            (N, 5+C, S, S) and (N, 4+C, L, L), uint8 (``float = value * 0.25``) or float.
        agent_class : ndarray
            (N,) class indices or (N, C) one-hot.
        action_mask : ndarray
            (N, A) bool, True = allowed.
        active : ndarray
            (N,) bool, robots that choose now (decided first, ascending id).
        deterministic : bool
            Argmax if True, else sample with ``rng``.

        Returns
        -------
        actions (N,) int64, log_probs (N,) float32, values (N,) float32. Busy robots get their first
        allowed ("keep") action and log-prob 0.
        """
        g, g_scale, l, l_scale, cls = self._inputs(global_map, local_map, agent_class)
        n, a = g.shape[0], self.config.num_actions
        mask = np.ascontiguousarray(action_mask, dtype=np.bool_)
        act = np.ascontiguousarray(active, dtype=np.bool_)
        if mask.shape != (n, a) or act.shape != (n,):
            raise ValueError(
                f"action_mask must be ({n}, {a}) and active ({n},), got {mask.shape}, {act.shape}"
            )
        if deterministic:
            u = np.zeros(n)
        elif rng is None:
            raise ValueError("sampling (deterministic=False) needs a numpy Generator rng")
        else:
            u = rng.random(n)
        actions, log_probs, values = np.empty(n, np.int64), np.empty(n, np.float32), np.empty(n, np.float32)
        maps = (g, g_scale, l, l_scale, cls, self._ones(g.shape[-1]), self._ones_local)
        cfg = self.config
        _decide(self._w, cfg.n_heads, cfg.pool, maps, mask, act, deterministic, u, actions, log_probs, values)
        return actions, log_probs, values

    def embed(self, global_map: np.ndarray, local_map: np.ndarray, agent_class: np.ndarray) -> np.ndarray:
        """Tokens (N, d), as ``AMAT.embed`` for one world."""
        g, g_scale, l, l_scale, cls = self._inputs(global_map, local_map, agent_class)
        ones = self._ones(g.shape[-1])
        return _embed(self._w, self.config.pool, g, g_scale, l, l_scale, cls, ones, self._ones_local)

    def encode(self, tokens: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(rep (N, d), values (N,)), as ``AMAT.encode`` for one world."""
        return _encode(self._w, self.config.n_heads, np.ascontiguousarray(tokens, dtype=np.float32))

    def global_conv(self, global_map: np.ndarray) -> np.ndarray:
        """The global convolution (N, 32, S, S) by the shared/sparse split (equals ``F.conv2d``)."""
        g, scale = _as_map(global_map)
        out = _global_conv_all(self._w, g, scale, self._ones(g.shape[-1]))
        return out.transpose(0, 3, 1, 2)

    # -- helpers ----------------------------------------------------------------------------------
    def _ones(self, s: int) -> np.ndarray:
        """(5+C, S, S, 32): the global convolution (no bias) of an all-ones channel, per channel."""
        if s not in self._ones_global:
            self._ones_global[s] = ones_conv(self._w.g_w, s, s)
        return self._ones_global[s]

    def _inputs(self, global_map, local_map, agent_class):
        cfg = self.config
        g, g_scale = _as_map(global_map)
        l, l_scale = _as_map(local_map)
        n, l_side = g.shape[0], cfg.local_size
        if g.ndim != 4 or g.shape[1] != cfg.global_channels or g.shape[2] != g.shape[3]:
            raise ValueError(f"global_map must be (N, {cfg.global_channels}, S, S), got {g.shape}")
        if l.shape != (n, cfg.local_channels, l_side, l_side):
            raise ValueError(
                f"local_map must be ({n}, {cfg.local_channels}, {l_side}, {l_side}), got {l.shape}"
            )
        cls = np.asarray(agent_class)
        if cls.ndim == 1:
            cls = np.eye(cfg.n_classes, dtype=np.float32)[cls]
        if cls.shape != (n, cfg.n_classes):
            raise ValueError(f"agent_class must be ({n},) or ({n}, {cfg.n_classes}), got {cls.shape}")
        return g, g_scale, l, l_scale, np.ascontiguousarray(cls, dtype=np.float32)


# -- weight extraction ----------------------------------------------------------------------------
def _numpy(t: Any) -> np.ndarray:
    if hasattr(t, "detach"):  # torch tensor
        t = t.detach().cpu().float().numpy()
    return np.asarray(t, dtype=np.float32)


def _gelu_np(x: np.ndarray) -> np.ndarray:
    x = x.astype(np.float64)
    erf = np.vectorize(math.erf)
    return (0.5 * x * (1.0 + erf(x / math.sqrt(2.0)))).astype(np.float32)


def _layer_norm_np(x: np.ndarray, weight: np.ndarray, bias: np.ndarray) -> np.ndarray:
    x = x.astype(np.float64)
    mean, var = x.mean(-1, keepdims=True), x.var(-1, keepdims=True)
    return (x - mean) / np.sqrt(var + _LN_EPS) * weight + bias


RUN_MAX = 8
"""Longest run of equal cells with a precomputed run kernel; longer runs are added in pieces."""


@_jit
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


@_jit
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
fields of ``_Weights``), also for callers of the kernels (``catmip_rl.amat.sparse_conv``). Defined here:
numba's cache of this module's kernels names the type."""


def conv_weights(weight: np.ndarray, bias: np.ndarray) -> ConvWeights:
    """A convolution (O, C, k, k) + bias (O,) in the kernels' layouts: flipped (C, k, k, O), its run
    kernels, torch's layout, the bias."""
    w = np.ascontiguousarray(weight, dtype=np.float32)
    flipped = np.ascontiguousarray(w[:, :, ::-1, ::-1].transpose(1, 2, 3, 0))
    b = np.ascontiguousarray(bias, dtype=np.float32)
    return ConvWeights(flipped, _run_kernels(flipped, RUN_MAX), w, b)


def _extract(cfg: AmatConfig, p: dict[str, np.ndarray]) -> _Weights:
    """Weights in the layouts the kernels read (see the field comments of ``_Weights``)."""
    d, g, l = cfg.embed_dim, cfg.pool, cfg.local_size
    f32 = np.ascontiguousarray

    def ln(name: str) -> np.ndarray:
        return f32(np.stack([p[f"{name}.weight"].ravel(), p[f"{name}.bias"].ravel()]))

    def ln_hwc(name: str) -> np.ndarray:  # (C, L, L) affine -> channel-last (L, L, C), flattened
        return f32(np.stack([p[f"{name}.{k}"].transpose(1, 2, 0).ravel() for k in ("weight", "bias")]))

    def blocks(prefix: str, n: int, key: str) -> np.ndarray:
        return f32(np.stack([p[f"{prefix}.{b}.{key}"] for b in range(n)]))

    def fused(prefix: str, n: int, parts: tuple[str, ...], kind: str) -> np.ndarray:
        return f32(
            np.stack([np.concatenate([p[f"{prefix}.{b}.{q}.{kind}"] for q in parts]) for b in range(n)])
        )

    def ln_blocks(prefix: str, n: int, name: str) -> np.ndarray:
        return f32(np.stack([ln(f"{prefix}.{b}.{name}") for b in range(n)]))

    fc1, w2 = p["obs_fc1.weight"], p["local_conv2.weight"]
    n_glob = p["global_conv.weight"].shape[0] * g * g
    fc1_local = (
        fc1[:, n_glob:].reshape(d, w2.shape[0], l, l).transpose(0, 2, 3, 1).reshape(d, -1)
    )  # (y, x, c)
    gconv = conv_weights(p["global_conv.weight"], p["global_conv.bias"])
    lconv = conv_weights(p["local_conv1.weight"], p["local_conv1.bias"])
    nb = cfg.n_blocks
    e, dd = "enc_blocks", "dec_blocks"
    d_qkv_w = fused(dd, nb, ("self_attn.q", "self_attn.k", "self_attn.v"), "weight")
    d_qkv_b = fused(dd, nb, ("self_attn.q", "self_attn.k", "self_attn.v"), "bias")
    act_tab = _gelu_np(p["action_enc.weight"].T)  # (A + 1, d): row 0 = start token
    dcls_tab = _gelu_np(p["dec_class_enc.weight"].T + p["dec_class_enc.bias"])  # (C, d): one-hot rows
    dx_tab = _layer_norm_np(act_tab[None] + dcls_tab[:, None], p["dec_ln.weight"], p["dec_ln.bias"])
    return _Weights(
        **gconv._asdict(),
        g_ln=ln("global_ln"),
        l1_w=lconv.g_w,
        l1_runs=lconv.g_runs,
        l1_torch=lconv.g_torch,
        l1_b=lconv.g_b,
        l1_ln=ln_hwc("local_ln1"),
        l2_w=f32(w2.transpose(0, 2, 3, 1).reshape(w2.shape[0], w2.shape[2], -1)),  # (out, ty, (tx, c))
        l2_b=p["local_conv2.bias"],
        l2_ln=ln_hwc("local_ln2"),
        fc1_w=f32(np.concatenate([fc1[:, :n_glob], fc1_local], axis=1)),
        fc1_b=p["obs_fc1.bias"],
        obs_ln=ln("obs_ln"),
        fc2_w=p["obs_fc2.weight"],
        fc2_b=p["obs_fc2.bias"],
        cls_w=p["class_enc.weight"],
        cls_b=p["class_enc.bias"],
        cls_tab=_gelu_np(p["class_enc.weight"].T + p["class_enc.bias"]),  # one-hot rows
        enc_ln=ln("enc_ln"),
        e_qkv_w=fused(e, nb, ("attn.q", "attn.k", "attn.v"), "weight"),
        e_qkv_b=fused(e, nb, ("attn.q", "attn.k", "attn.v"), "bias"),
        e_out_w=blocks(e, nb, "attn.out.weight"),
        e_out_b=blocks(e, nb, "attn.out.bias"),
        e_ln1=ln_blocks(e, nb, "ln1"),
        e_fc1_w=blocks(e, nb, "mlp.0.weight"),
        e_fc1_b=blocks(e, nb, "mlp.0.bias"),
        e_fc2_w=blocks(e, nb, "mlp.2.weight"),
        e_fc2_b=blocks(e, nb, "mlp.2.bias"),
        e_ln2=ln_blocks(e, nb, "ln2"),
        v_w1=p["value_head.0.weight"],
        v_b1=p["value_head.0.bias"],
        v_ln=ln("value_head.2"),
        v_w2=p["value_head.3.weight"],
        v_b2=p["value_head.3.bias"],
        act_tab=act_tab,
        dcls_w=p["dec_class_enc.weight"],
        dcls_b=p["dec_class_enc.bias"],
        dcls_tab=dcls_tab,
        dec_ln=ln("dec_ln"),
        dx_tab=f32(dx_tab),  # (C, A + 1, d): decoder input of a one-hot class after each action
        dqkv_tab=f32(dx_tab @ d_qkv_w[0].T.astype(np.float64) + d_qkv_b[0]),  # (C, A + 1, 3d), block 0
        d_qkv_w=d_qkv_w,
        d_qkv_b=d_qkv_b,
        d_sout_w=blocks(dd, nb, "self_attn.out.weight"),
        d_sout_b=blocks(dd, nb, "self_attn.out.bias"),
        d_ln1=ln_blocks(dd, nb, "ln1"),
        d_q_w=blocks(dd, nb, "cross_attn.q.weight"),
        d_q_b=blocks(dd, nb, "cross_attn.q.bias"),
        d_kv_w=fused(dd, nb, ("cross_attn.k", "cross_attn.v"), "weight"),
        d_kv_b=fused(dd, nb, ("cross_attn.k", "cross_attn.v"), "bias"),
        d_cout_w=blocks(dd, nb, "cross_attn.out.weight"),
        d_cout_b=blocks(dd, nb, "cross_attn.out.bias"),
        d_ln2=ln_blocks(dd, nb, "ln2"),
        d_fc1_w=blocks(dd, nb, "mlp.0.weight"),
        d_fc1_b=blocks(dd, nb, "mlp.0.bias"),
        d_fc2_w=blocks(dd, nb, "mlp.2.weight"),
        d_fc2_b=blocks(dd, nb, "mlp.2.bias"),
        d_ln3=ln_blocks(dd, nb, "ln3"),
        h_w1=p["policy_head.0.weight"],
        h_b1=p["policy_head.0.bias"],
        h_ln=ln("policy_head.2"),
        h_w2=p["policy_head.3.weight"],
        h_b2=p["policy_head.3.bias"],
    )


def _as_map(x: np.ndarray) -> tuple[np.ndarray, np.float32]:
    """(contiguous uint8 or float32 map, scale): uint8 reads as value * 0.25, as ``AMAT.embed``."""
    x = np.asarray(x)
    if x.dtype == np.uint8:
        return np.ascontiguousarray(x), np.float32(OBS_SCALE)
    return np.ascontiguousarray(x, dtype=np.float32), np.float32(1.0)


# -- small numeric kernels --------------------------------------------------------------------------
@_jit
def _matvec(x, w, b, out):
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


@_jit
def _linear(x, w, b, out):
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


@_jit
def _layer_norm(x, wb, out):
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
    mean32, inv32 = np.float32(mean), np.float32(1.0 / math.sqrt(v / n + _LN_EPS))
    for j in range(n):
        out[j] = (x[j] - mean32) * inv32 * wb[0, j] + wb[1, j]


@_jit
def _dot(x, y):
    s = np.float32(0.0)
    for j in range(x.size):
        s += x[j] * y[j]
    return s


@_jit
def _fill(out, b):
    """out (H, W, O)[y, x] = b (O,) everywhere."""
    for y in range(out.shape[0]):
        for x in range(out.shape[1]):
            out[y, x] = b


@_jit
def _relu(x):
    for j in range(x.size):
        x[j] = np.maximum(x[j], np.float32(0.0))  # np.maximum vectorises, max() does not


@_jit
def _copy(out, x):
    """out[:] = x for equal-shape C-contiguous arrays (a flat loop that vectorises)."""
    o_flat, x_flat = out.ravel(), x.ravel()
    for j in range(o_flat.size):
        o_flat[j] = x_flat[j]


# erf(z) ~ z P(z^2) / Q(z^2) on [-4, 4] (Eigen's single-precision rational; in float64 the error is
# below 7e-8, less than torch's own float32 erf): branch-free, so the GELU loop vectorises.
_ERF_P = (-1.60960333262415e-02, -2.95459980854025e-03, -7.34990630326855e-04, -5.69250639462346e-05,
          -2.10102402082508e-06, 2.77068142495902e-08, -2.72614225801306e-10)  # fmt: skip
_ERF_Q = (-1.42647390514189e-02, -7.37332916720468e-03, -1.68282697438203e-03, -2.13374055278905e-04,
          -1.45660718464996e-05)  # fmt: skip


@_jit
def _gelu(x):
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


@_jit
def _add_ln(x, y, wb, out):
    """out = LayerNorm(x + y); out may be x or y."""
    for j in range(x.size):
        out[j] = x[j] + y[j]
    _layer_norm(out, wb, out)


@_jit
def _attend(q, keys, values, t, n_heads, scores, out):
    """Softmax attention of one query (d,) over the first t rows of keys / values (T, d), per head."""
    dh = q.size // n_heads
    scale = 1.0 / math.sqrt(dh)
    for h in range(n_heads):
        lo, hi = h * dh, (h + 1) * dh
        qh, oh = q[lo:hi], out[lo:hi]
        top = -np.inf
        for j in range(t):
            scores[j] = _dot(qh, keys[j, lo:hi]) * scale
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


@_jit
def _one_hot(c):
    """Index of the 1 if c is exactly one-hot, else -1."""
    hot = -1
    for j in range(c.size):
        if c[j] == 1.0 and hot < 0:
            hot = j
        elif c[j] != 0.0:
            return -1
    return hot


@_jit
def _class_token(c, tab, w, b, out):
    """GELU(Linear(c)) (d,): a table row for a one-hot c, else computed."""
    hot = _one_hot(c)
    if hot >= 0:
        out[:] = tab[hot]
    else:
        _matvec(c, w, b, out)
        _gelu(out)


# -- convolutions -----------------------------------------------------------------------------------
@_jit
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


@_jit
def _count_ne(x, y, ref):
    """Entries of the 1-D x - y that differ from ref (a loop that vectorises)."""
    cnt = 0
    for j in range(x.size):
        cnt += float(x[j]) - float(y[j]) != ref
    return cnt


@_jit
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


@_jit
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


@_jit
def _dense_conv(out, w_torch, planes, chans, scale):
    """out (H, W, O) += the convolution of ``planes[chans] * scale`` (zero padding), by ``_conv_rows``
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
    _conv_rows(xp, w_sel, np.zeros(n_out, np.float32), res)
    o_flat, r_flat = out.ravel(), res.ravel()
    for j in range(o_flat.size):
        o_flat[j] += r_flat[j]


@_jit
def _add_planes(out, conv, ones, planes, ch0, ch1, zero, scale):
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


@_jit
def _shared_base(w, gmap, scale, ones, zero, base):
    """base (S, S, O) = bias + robot 0's convolution of the shared channels (explored, occupied, target)."""
    _fill(base, w.g_b)
    _add_planes(base, (w.g_runs, w.g_torch), ones, gmap[0], 0, min(_SHARED, gmap.shape[1]), zero, scale)
    return base


@_jit
def _robot_conv(w, gmap, i, scale, ones, zero, base, out):
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
        _copy(out, base)
        if diff:
            for ch in range(shared):
                _add_runs(out, w.g_runs[ch], gmap[i, ch], gmap[0, ch], 0.0, scale)
        first = shared
    else:
        _fill(out, w.g_b)
        first = 0
    _add_planes(out, conv, ones, gmap[i], first, gmap.shape[1], zero, scale)


@_jit
def _global_conv_all(w, gmap, scale, ones):
    """(N, S, S, O): every robot's global convolution (channel-last)."""
    zero = np.zeros(gmap.shape[2:], gmap.dtype)
    base = _shared_base(w, gmap, scale, ones, zero, np.empty(gmap.shape[2:] + (w.g_b.size,), np.float32))
    out = np.empty((gmap.shape[0], gmap.shape[2], gmap.shape[3], w.g_b.size), np.float32)
    for i in range(gmap.shape[0]):
        _robot_conv(w, gmap, i, scale, ones, zero, base, out[i])
    return out


@_jit
def _conv_rows(xp, w, b, out):
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


@_jit
def _pool(x, g, out):
    """Adaptive max pool of x (S, S, O) to out (O * g * g,) in (o, gy, gx) order (torch's bins)."""
    h, wd, n_out = x.shape
    x_flat = x.ravel()
    row = wd * n_out
    col_max = np.empty(row, np.float32)
    for gy in range(g):
        y0, y1 = gy * h // g, ((gy + 1) * h + g - 1) // g
        _copy(col_max, x_flat[y0 * row : (y0 + 1) * row])
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


# -- the network ------------------------------------------------------------------------------------
@_jit
def _embed(w, pool, gmap, g_scale, lmap, l_scale, cls, ones_g, ones_l):
    """Tokens (N, d) of one world (``AMAT.embed``)."""
    n, s = gmap.shape[0], gmap.shape[2]
    side = lmap.shape[2]
    c1, c2 = w.l1_b.size, w.l2_b.size
    n_glob = w.g_ln.shape[1]
    area = side * side
    feats = np.empty((n, w.fc1_w.shape[1]), np.float32)
    # global CNN -> pooled, LayerNorm, ReLU
    zero = np.zeros((s, s), gmap.dtype)
    base = _shared_base(w, gmap, g_scale, ones_g, zero, np.empty((s, s, w.g_b.size), np.float32))
    work = np.empty((s, s, w.g_b.size), np.float32)
    for i in range(n):
        _robot_conv(w, gmap, i, g_scale, ones_g, zero, base, work)
        head = feats[i, :n_glob]
        _pool(work, pool, head)
        _layer_norm(head, w.g_ln, head)
        _relu(head)
    # local CNN: conv1 by scatter, conv2 densely on the zero-padded conv1 output
    h1 = np.empty((side, side, c1), np.float32)
    h1_pad = np.zeros((side + 2, side + 2, c1), np.float32)
    h2 = np.empty((area, c2), np.float32)
    zero_l = np.zeros((side, side), lmap.dtype)
    for i in range(n):
        _fill(h1, w.l1_b)
        _add_planes(h1, (w.l1_runs, w.l1_torch), ones_l, lmap[i], 0, lmap.shape[1], zero_l, l_scale)
        h1_flat = h1.ravel()
        _layer_norm(h1_flat, w.l1_ln, h1_flat)
        _relu(h1_flat)
        for y in range(side):
            h1_pad[y + 1, 1 : side + 1] = h1[y]
        _conv_rows(h1_pad, w.l2_w, w.l2_b, h2)
        tail = feats[i, n_glob:]
        _layer_norm(h2.ravel(), w.l2_ln, tail)
        _relu(tail)
    # observation MLP plus the class encoding
    d = w.fc1_b.size
    h = np.empty((n, d), np.float32)
    tok = np.empty((n, d), np.float32)
    _linear(feats, w.fc1_w, w.fc1_b, h)
    for i in range(n):
        _gelu(h[i])
        _layer_norm(h[i], w.obs_ln, h[i])
    _linear(h, w.fc2_w, w.fc2_b, tok)
    ctok = np.empty(d, np.float32)
    for i in range(n):
        _gelu(tok[i])
        _class_token(cls[i], w.cls_tab, w.cls_w, w.cls_b, ctok)
        tok[i] += ctok
    return tok


@_jit
def _encode(w, n_heads, tokens):
    """(rep (N, d), values (N,)) of one world (``AMAT.encode``, no padding)."""
    n, d = tokens.shape
    x = np.empty((n, d), np.float32)
    for i in range(n):
        _layer_norm(tokens[i], w.enc_ln, x[i])
    qkv = np.empty((n, 3 * d), np.float32)
    y, t = np.empty((n, d), np.float32), np.empty((n, d), np.float32)
    scores = np.empty(n, np.float32)
    for blk in range(w.e_qkv_w.shape[0]):
        _linear(x, w.e_qkv_w[blk], w.e_qkv_b[blk], qkv)
        for i in range(n):
            _attend(qkv[i, :d], qkv[:, d : 2 * d], qkv[:, 2 * d :], n, n_heads, scores, y[i])
        _linear(y, w.e_out_w[blk], w.e_out_b[blk], t)
        for i in range(n):
            _add_ln(x[i], t[i], w.e_ln1[blk], x[i])
        _linear(x, w.e_fc1_w[blk], w.e_fc1_b[blk], y)
        for i in range(n):
            _gelu(y[i])
        _linear(y, w.e_fc2_w[blk], w.e_fc2_b[blk], t)
        for i in range(n):
            _add_ln(x[i], t[i], w.e_ln2[blk], x[i])
    values = np.empty(n, np.float32)
    _linear(x, w.v_w1, w.v_b1, y)
    for i in range(n):
        _gelu(y[i])
        _layer_norm(y[i], w.v_ln, y[i])
        values[i] = _dot(y[i], w.v_w2[0]) + w.v_b2[0]
    return x, values


@_jit
def _decode(w, n_heads, rep, cls, mask, active, deterministic, u, actions, log_probs):
    """Autoregressive decoding of the active robots (``AMAT.decode_autoregressive``), in place."""
    n, d = rep.shape
    n_act = mask.shape[1]
    order = np.empty(n, np.int64)
    steps = 0
    for i in range(n):
        actions[i], log_probs[i] = 0, 0.0
        for a in range(n_act):
            if mask[i, a]:
                actions[i] = a  # busy robots: the first allowed ("keep") action
                break
        if active[i]:
            order[steps] = i
            steps += 1
    if steps == 0:
        return
    n_blocks = w.d_qkv_w.shape[0]
    rep_o = np.empty((steps, d), np.float32)
    for k in range(steps):
        rep_o[k] = rep[order[k]]
    q_cross = np.empty((n_blocks, steps, d), np.float32)
    for blk in range(n_blocks):
        _linear(rep_o, w.d_q_w[blk], w.d_q_b[blk], q_cross[blk])
    k_self, v_self = np.empty((n_blocks, steps, d), np.float32), np.empty((n_blocks, steps, d), np.float32)
    k_cross, v_cross = np.empty((n_blocks, steps, d), np.float32), np.empty((n_blocks, steps, d), np.float32)
    x, y, t = np.empty(d, np.float32), np.empty(d, np.float32), np.empty(d, np.float32)
    qkv, kv = np.empty(3 * d, np.float32), np.empty(2 * d, np.float32)
    logits, scores = np.empty(n_act, np.float32), np.empty(steps, np.float32)
    prev = 0  # start token
    for k in range(steps):
        i = order[k]
        hot = _one_hot(cls[i])
        if hot >= 0:  # tabulated: the decoder input and block 0's q/k/v depend only on (class, prev)
            x[:] = w.dx_tab[hot, prev]
        else:
            _class_token(cls[i], w.dcls_tab, w.dcls_w, w.dcls_b, y)
            _add_ln(w.act_tab[prev], y, w.dec_ln, x)
        for blk in range(n_blocks):
            if blk == 0 and hot >= 0:
                qkv[:] = w.dqkv_tab[hot, prev]
            else:
                _matvec(x, w.d_qkv_w[blk], w.d_qkv_b[blk], qkv)
            k_self[blk, k], v_self[blk, k] = qkv[d : 2 * d], qkv[2 * d :]
            _attend(qkv[:d], k_self[blk], v_self[blk], k + 1, n_heads, scores, y)
            _matvec(y, w.d_sout_w[blk], w.d_sout_b[blk], t)
            _add_ln(x, t, w.d_ln1[blk], x)
            _matvec(x, w.d_kv_w[blk], w.d_kv_b[blk], kv)
            k_cross[blk, k], v_cross[blk, k] = kv[:d], kv[d:]
            _attend(q_cross[blk, k], k_cross[blk], v_cross[blk], k + 1, n_heads, scores, y)
            _matvec(y, w.d_cout_w[blk], w.d_cout_b[blk], t)
            _add_ln(rep_o[k], t, w.d_ln2[blk], x)
            _matvec(x, w.d_fc1_w[blk], w.d_fc1_b[blk], y)
            _gelu(y)
            _matvec(y, w.d_fc2_w[blk], w.d_fc2_b[blk], t)
            _add_ln(x, t, w.d_ln3[blk], x)
        _matvec(x, w.h_w1, w.h_b1, y)
        _gelu(y)
        _layer_norm(y, w.h_ln, y)
        _matvec(y, w.h_w2, w.h_b2, logits)
        a, lp = _choose(logits, mask[i], deterministic, u[k])
        actions[i], log_probs[i] = a, lp
        prev = a + 1


@_jit
def _choose(logits, allowed, deterministic, u):
    """(action, log-prob) from masked logits: argmax (first maximum) or inverse-CDF sampling at u."""
    best = 0
    for a in range(logits.size):
        if not allowed[a]:
            logits[a] = INVALID_LOGIT
        if logits[a] > logits[best]:
            best = a
    top = float(logits[best])
    total = 0.0
    for a in range(logits.size):
        total += math.exp(logits[a] - top)
    lse = top + math.log(total)
    if not deterministic:
        target, cum = u * total, 0.0
        for a in range(logits.size):
            p = math.exp(logits[a] - top)
            if p > 0.0:
                best = a
                cum += p
                if cum > target:
                    break
    return best, np.float32(logits[best] - lse)


@_jit
def _decide(w, n_heads, pool, maps, mask, active, deterministic, u, actions, log_probs, values):
    """embed -> encode -> decode; writes actions, log-probs and values (N,) in place.

    ``maps`` = (global map, its scale, local map, its scale, classes (N, C), global and local
    ones-convolutions).
    """
    gmap, g_scale, lmap, l_scale, cls, ones_g, ones_l = maps
    rep, v = _encode(w, n_heads, _embed(w, pool, gmap, g_scale, lmap, l_scale, cls, ones_g, ones_l))
    values[:] = v
    _decode(w, n_heads, rep, cls, mask, active, deterministic, u, actions, log_probs)
