"""Fast batch-1 AMAT decisions on CPU: numba kernels over weights snapshotted from an :class:`AMAT`.

>>> fast = FastAmat.from_model(model)     # copies the weights: rebuild it after the model changes
>>> actions, log_probs, values = fast.decide(global_map, local_map, agent_class, action_mask, active)

One world (no batch axis): embed every robot, encode, decode the active robots autoregressively, as
``model.embed`` -> ``model.encode`` -> ``model.decode_autoregressive`` (same argmax actions; log-probs and
values equal to float32 rounding), in one numba call, without torch. What makes it fast:

* the convolutions on the maps are linear and the maps sparse: each input channel adds its majority
  value times a precomputed convolution of ones plus precomputed run kernels for the runs of cells that
  differ, and the global map's shared belief channels are convolved once per world (``kernels.conv``);
* d-sized matrix products in register tiles (``numba_ops``); the decoder's first-block input and q/k/v
  projections, which depend only on (class, previous action), are tabulated (``snapshot``); exact
  GELU by a branch-free rational erf (error below 1e-7).

This module holds :class:`FastAmat` and the network's kernels (embed, encode, decode, the whole
decision); the weights snapshot is ``snapshot``, the kernels it calls ``kernels.conv`` and
``numba_ops``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from catmip_env.constants import OBS_SCALE
from catmip_rl.amat.config import AmatConfig
from catmip_rl.amat.kernels.conv import (
    add_planes,
    conv_rows,
    global_conv_all,
    max_pool,
    ones_conv,
    robot_conv,
    shared_base,
)
from catmip_rl.amat.kernels.numba_ops import (
    add_ln,
    attend,
    class_token,
    dot,
    fill,
    gelu,
    kernel,
    layer_norm,
    linear,
    matvec,
    one_hot,
    relu,
)
from catmip_rl.amat.model import INVALID_LOGIT
from catmip_rl.amat.onboard.snapshot import extract_weights

__all__ = ["FastAmat"]


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
        self._w = extract_weights(config, state_dict)
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
        out = global_conv_all(self._w, g, scale, self._ones(g.shape[-1]))
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


def _as_map(x: np.ndarray) -> tuple[np.ndarray, np.float32]:
    """(contiguous uint8 or float32 map, scale): uint8 reads as value * 0.25, as ``AMAT.embed``."""
    x = np.asarray(x)
    if x.dtype == np.uint8:
        return np.ascontiguousarray(x), np.float32(OBS_SCALE)
    return np.ascontiguousarray(x, dtype=np.float32), np.float32(1.0)


# -- the network ------------------------------------------------------------------------------------
@kernel
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
    base = shared_base(w, gmap, g_scale, ones_g, zero, np.empty((s, s, w.g_b.size), np.float32))
    work = np.empty((s, s, w.g_b.size), np.float32)
    for i in range(n):
        robot_conv(w, gmap, i, g_scale, ones_g, zero, base, work)
        head = feats[i, :n_glob]
        max_pool(work, pool, head)
        layer_norm(head, w.g_ln, head)
        relu(head)
    # local CNN: conv1 by scatter, conv2 densely on the zero-padded conv1 output
    h1 = np.empty((side, side, c1), np.float32)
    h1_pad = np.zeros((side + 2, side + 2, c1), np.float32)
    h2 = np.empty((area, c2), np.float32)
    zero_l = np.zeros((side, side), lmap.dtype)
    for i in range(n):
        fill(h1, w.l1_b)
        add_planes(h1, (w.l1_runs, w.l1_torch), ones_l, lmap[i], 0, lmap.shape[1], zero_l, l_scale)
        h1_flat = h1.ravel()
        layer_norm(h1_flat, w.l1_ln, h1_flat)
        relu(h1_flat)
        for y in range(side):
            h1_pad[y + 1, 1 : side + 1] = h1[y]
        conv_rows(h1_pad, w.l2_w, w.l2_b, h2)
        tail = feats[i, n_glob:]
        layer_norm(h2.ravel(), w.l2_ln, tail)
        relu(tail)
    # observation MLP plus the class encoding
    d = w.fc1_b.size
    h = np.empty((n, d), np.float32)
    tok = np.empty((n, d), np.float32)
    linear(feats, w.fc1_w, w.fc1_b, h)
    for i in range(n):
        gelu(h[i])
        layer_norm(h[i], w.obs_ln, h[i])
    linear(h, w.fc2_w, w.fc2_b, tok)
    ctok = np.empty(d, np.float32)
    for i in range(n):
        gelu(tok[i])
        class_token(cls[i], w.cls_tab, w.cls_w, w.cls_b, ctok)
        tok[i] += ctok
    return tok


@kernel
def _encode(w, n_heads, tokens):
    """(rep (N, d), values (N,)) of one world (``AMAT.encode``, no padding)."""
    n, d = tokens.shape
    x = np.empty((n, d), np.float32)
    for i in range(n):
        layer_norm(tokens[i], w.enc_ln, x[i])
    qkv = np.empty((n, 3 * d), np.float32)
    y, t = np.empty((n, d), np.float32), np.empty((n, d), np.float32)
    scores = np.empty(n, np.float32)
    for blk in range(w.e_qkv_w.shape[0]):
        linear(x, w.e_qkv_w[blk], w.e_qkv_b[blk], qkv)
        for i in range(n):
            attend(qkv[i, :d], qkv[:, d : 2 * d], qkv[:, 2 * d :], n, n_heads, scores, y[i])
        linear(y, w.e_out_w[blk], w.e_out_b[blk], t)
        for i in range(n):
            add_ln(x[i], t[i], w.e_ln1[blk], x[i])
        linear(x, w.e_fc1_w[blk], w.e_fc1_b[blk], y)
        for i in range(n):
            gelu(y[i])
        linear(y, w.e_fc2_w[blk], w.e_fc2_b[blk], t)
        for i in range(n):
            add_ln(x[i], t[i], w.e_ln2[blk], x[i])
    values = np.empty(n, np.float32)
    linear(x, w.v_w1, w.v_b1, y)
    for i in range(n):
        gelu(y[i])
        layer_norm(y[i], w.v_ln, y[i])
        values[i] = dot(y[i], w.v_w2[0]) + w.v_b2[0]
    return x, values


@kernel
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
        linear(rep_o, w.d_q_w[blk], w.d_q_b[blk], q_cross[blk])
    k_self, v_self = np.empty((n_blocks, steps, d), np.float32), np.empty((n_blocks, steps, d), np.float32)
    k_cross, v_cross = np.empty((n_blocks, steps, d), np.float32), np.empty((n_blocks, steps, d), np.float32)
    x, y, t = np.empty(d, np.float32), np.empty(d, np.float32), np.empty(d, np.float32)
    qkv, kv = np.empty(3 * d, np.float32), np.empty(2 * d, np.float32)
    logits, scores = np.empty(n_act, np.float32), np.empty(steps, np.float32)
    prev = 0  # start token
    for k in range(steps):
        i = order[k]
        hot = one_hot(cls[i])
        if hot >= 0:  # tabulated: the decoder input and block 0's q/k/v depend only on (class, prev)
            x[:] = w.dx_tab[hot, prev]
        else:
            class_token(cls[i], w.dcls_tab, w.dcls_w, w.dcls_b, y)
            add_ln(w.act_tab[prev], y, w.dec_ln, x)
        for blk in range(n_blocks):
            if blk == 0 and hot >= 0:
                qkv[:] = w.dqkv_tab[hot, prev]
            else:
                matvec(x, w.d_qkv_w[blk], w.d_qkv_b[blk], qkv)
            k_self[blk, k], v_self[blk, k] = qkv[d : 2 * d], qkv[2 * d :]
            attend(qkv[:d], k_self[blk], v_self[blk], k + 1, n_heads, scores, y)
            matvec(y, w.d_sout_w[blk], w.d_sout_b[blk], t)
            add_ln(x, t, w.d_ln1[blk], x)
            matvec(x, w.d_kv_w[blk], w.d_kv_b[blk], kv)
            k_cross[blk, k], v_cross[blk, k] = kv[:d], kv[d:]
            attend(q_cross[blk, k], k_cross[blk], v_cross[blk], k + 1, n_heads, scores, y)
            matvec(y, w.d_cout_w[blk], w.d_cout_b[blk], t)
            add_ln(rep_o[k], t, w.d_ln2[blk], x)
            matvec(x, w.d_fc1_w[blk], w.d_fc1_b[blk], y)
            gelu(y)
            matvec(y, w.d_fc2_w[blk], w.d_fc2_b[blk], t)
            add_ln(x, t, w.d_ln3[blk], x)
        matvec(x, w.h_w1, w.h_b1, y)
        gelu(y)
        layer_norm(y, w.h_ln, y)
        matvec(y, w.h_w2, w.h_b2, logits)
        a, lp = _choose(logits, mask[i], deterministic, u[k])
        actions[i], log_probs[i] = a, lp
        prev = a + 1


@kernel
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


@kernel
def _decide(w, n_heads, pool, maps, mask, active, deterministic, u, actions, log_probs, values):
    """embed -> encode -> decode; writes actions, log-probs and values (N,) in place.

    ``maps`` = (global map, its scale, local map, its scale, classes (N, C), global and local
    ones-convolutions).
    """
    gmap, g_scale, lmap, l_scale, cls, ones_g, ones_l = maps
    rep, v = _encode(w, n_heads, _embed(w, pool, gmap, g_scale, lmap, l_scale, cls, ones_g, ones_l))
    values[:] = v
    _decode(w, n_heads, rep, cls, mask, active, deterministic, u, actions, log_probs)
