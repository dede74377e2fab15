"""The weights snapshot of :class:`~catmip_rl.amat.onboard.fast_amat.FastAmat`: an ``AMAT.state_dict()``
copied into numpy float32 arrays in the layouts its numba kernels read (:class:`FastWeights`).

Convolutions go to the sparse kernels' layouts (:func:`~catmip_rl.amat.kernels.conv.conv_weights`), the
local CNN's activations and LayerNorms channel-last, per-block tensors stacked along axis 0, q/k/v
projections of one input concatenated; the class tokens, the macro-action embeddings and the decoder's
first-block input and q/k/v projections, which depend only on (class, previous action), are tabulated.
"""

from __future__ import annotations

import math
from collections import namedtuple
from collections.abc import Mapping
from typing import Any

import numpy as np

from catmip_rl.amat.config import AmatConfig
from catmip_rl.amat.kernels.conv import conv_weights
from catmip_rl.amat.kernels.numba_ops import LN_EPS

__all__ = ["FastWeights", "extract_weights"]

FastWeights = namedtuple(
    "FastWeights",
    [
        # embedder: convolutions in scatter layout (in, flipped ky, flipped kx, out), with run kernels
        # and a dense layout; LayerNorms as (2, n) = weight, bias; local activations channel-last
        "g_w",
        "g_runs",
        "g_torch",
        "g_b",
        "g_ln",
        "l1_w",
        "l1_runs",
        "l1_torch",
        "l1_b",
        "l1_ln",
        "l2_w",
        "l2_b",
        "l2_ln",
        "fc1_w",
        "fc1_b",
        "obs_ln",
        "fc2_w",
        "fc2_b",
        "cls_w",
        "cls_b",
        "cls_tab",
        # encoder (per-block tensors stacked along axis 0) and value head
        "enc_ln",
        "e_qkv_w",
        "e_qkv_b",
        "e_out_w",
        "e_out_b",
        "e_ln1",
        "e_fc1_w",
        "e_fc1_b",
        "e_fc2_w",
        "e_fc2_b",
        "e_ln2",
        "v_w1",
        "v_b1",
        "v_ln",
        "v_w2",
        "v_b2",
        # macro-action embedder, decoder, policy head
        "act_tab",
        "dcls_w",
        "dcls_b",
        "dcls_tab",
        "dec_ln",
        "dx_tab",
        "dqkv_tab",
        "d_qkv_w",
        "d_qkv_b",
        "d_sout_w",
        "d_sout_b",
        "d_ln1",
        "d_q_w",
        "d_q_b",
        "d_kv_w",
        "d_kv_b",
        "d_cout_w",
        "d_cout_b",
        "d_ln2",
        "d_fc1_w",
        "d_fc1_b",
        "d_fc2_w",
        "d_fc2_b",
        "d_ln3",
        "h_w1",
        "h_b1",
        "h_ln",
        "h_w2",
        "h_b2",
    ],
)


def extract_weights(config: AmatConfig, state_dict: Mapping[str, Any]) -> FastWeights:
    """``AMAT.state_dict()`` (torch tensors or numpy arrays) in the layouts the kernels read (see the
    field comments of ``FastWeights``): a copy, not a view of the model's parameters."""
    p = _Params({k: _numpy(v) for k, v in state_dict.items()}, config.n_blocks)
    return FastWeights(**_embedder(config, p), **_encoder(p), **_decoder(p))


class _Params:
    """The state dict's float32 arrays, and the lookups that stack them into the kernels' layouts."""

    def __init__(self, arrays: dict[str, np.ndarray], n_blocks: int) -> None:
        self.arrays, self.n_blocks = arrays, n_blocks

    def __getitem__(self, key: str) -> np.ndarray:
        return self.arrays[key]

    def ln(self, name: str) -> np.ndarray:
        """(2, n): a LayerNorm's weight and bias."""
        return np.ascontiguousarray(np.stack([self[f"{name}.weight"].ravel(), self[f"{name}.bias"].ravel()]))

    def ln_hwc(self, name: str) -> np.ndarray:
        """(2, L * L * C): a (C, L, L) LayerNorm's affine channel-last (L, L, C), flattened."""
        parts = [self[f"{name}.{k}"].transpose(1, 2, 0).ravel() for k in ("weight", "bias")]
        return np.ascontiguousarray(np.stack(parts))

    def blocks(self, prefix: str, key: str) -> np.ndarray:
        """(blocks, ...): one tensor of every block, stacked."""
        return np.ascontiguousarray(np.stack([self[f"{prefix}.{b}.{key}"] for b in range(self.n_blocks)]))

    def fused(self, prefix: str, parts: tuple[str, ...], kind: str) -> np.ndarray:
        """(blocks, len(parts) * d, ...): the ``kind`` (weight / bias) of linear layers on one input,
        concatenated along the output dimension, per block."""
        per_block = [
            np.concatenate([self[f"{prefix}.{b}.{q}.{kind}"] for q in parts]) for b in range(self.n_blocks)
        ]
        return np.ascontiguousarray(np.stack(per_block))

    def ln_blocks(self, prefix: str, name: str) -> np.ndarray:
        """(blocks, 2, n): a LayerNorm of every block."""
        return np.ascontiguousarray(np.stack([self.ln(f"{prefix}.{b}.{name}") for b in range(self.n_blocks)]))


def _embedder(cfg: AmatConfig, p: _Params) -> dict[str, np.ndarray]:
    d, g, l = cfg.embed_dim, cfg.pool, cfg.local_size
    fc1, w2 = p["obs_fc1.weight"], p["local_conv2.weight"]
    n_glob = p["global_conv.weight"].shape[0] * g * g
    # the local features' columns of obs_fc1 in the (y, x, c) order of the kernels' activations
    fc1_local = fc1[:, n_glob:].reshape(d, w2.shape[0], l, l).transpose(0, 2, 3, 1).reshape(d, -1)
    l2_w = w2.transpose(0, 2, 3, 1).reshape(w2.shape[0], w2.shape[2], -1)  # (out, ty, (tx, c))
    gconv = conv_weights(p["global_conv.weight"], p["global_conv.bias"])
    lconv = conv_weights(p["local_conv1.weight"], p["local_conv1.bias"])
    return dict(
        **gconv._asdict(),
        g_ln=p.ln("global_ln"),
        l1_w=lconv.g_w,
        l1_runs=lconv.g_runs,
        l1_torch=lconv.g_torch,
        l1_b=lconv.g_b,
        l1_ln=p.ln_hwc("local_ln1"),
        l2_w=np.ascontiguousarray(l2_w),
        l2_b=p["local_conv2.bias"],
        l2_ln=p.ln_hwc("local_ln2"),
        fc1_w=np.ascontiguousarray(np.concatenate([fc1[:, :n_glob], fc1_local], axis=1)),
        fc1_b=p["obs_fc1.bias"],
        obs_ln=p.ln("obs_ln"),
        fc2_w=p["obs_fc2.weight"],
        fc2_b=p["obs_fc2.bias"],
        cls_w=p["class_enc.weight"],
        cls_b=p["class_enc.bias"],
        cls_tab=_gelu_np(p["class_enc.weight"].T + p["class_enc.bias"]),  # one-hot rows
    )


def _encoder(p: _Params) -> dict[str, np.ndarray]:
    e = "enc_blocks"
    return dict(
        enc_ln=p.ln("enc_ln"),
        e_qkv_w=p.fused(e, ("attn.q", "attn.k", "attn.v"), "weight"),
        e_qkv_b=p.fused(e, ("attn.q", "attn.k", "attn.v"), "bias"),
        e_out_w=p.blocks(e, "attn.out.weight"),
        e_out_b=p.blocks(e, "attn.out.bias"),
        e_ln1=p.ln_blocks(e, "ln1"),
        e_fc1_w=p.blocks(e, "mlp.0.weight"),
        e_fc1_b=p.blocks(e, "mlp.0.bias"),
        e_fc2_w=p.blocks(e, "mlp.2.weight"),
        e_fc2_b=p.blocks(e, "mlp.2.bias"),
        e_ln2=p.ln_blocks(e, "ln2"),
        v_w1=p["value_head.0.weight"],
        v_b1=p["value_head.0.bias"],
        v_ln=p.ln("value_head.2"),
        v_w2=p["value_head.3.weight"],
        v_b2=p["value_head.3.bias"],
    )


def _decoder(p: _Params) -> dict[str, np.ndarray]:
    dd = "dec_blocks"
    d_qkv_w = p.fused(dd, ("self_attn.q", "self_attn.k", "self_attn.v"), "weight")
    d_qkv_b = p.fused(dd, ("self_attn.q", "self_attn.k", "self_attn.v"), "bias")
    act_tab = _gelu_np(p["action_enc.weight"].T)  # (A + 1, d): row 0 = start token
    dcls_tab = _gelu_np(p["dec_class_enc.weight"].T + p["dec_class_enc.bias"])  # (C, d): one-hot rows
    # (C, A + 1, d): the decoder input of a one-hot class after each action; (C, A + 1, 3d): block 0's q/k/v
    dx_tab = _layer_norm_np(act_tab[None] + dcls_tab[:, None], p["dec_ln.weight"], p["dec_ln.bias"])
    dqkv_tab = dx_tab @ d_qkv_w[0].T.astype(np.float64) + d_qkv_b[0]
    return dict(
        act_tab=act_tab,
        dcls_w=p["dec_class_enc.weight"],
        dcls_b=p["dec_class_enc.bias"],
        dcls_tab=dcls_tab,
        dec_ln=p.ln("dec_ln"),
        dx_tab=np.ascontiguousarray(dx_tab),
        dqkv_tab=np.ascontiguousarray(dqkv_tab),
        d_qkv_w=d_qkv_w,
        d_qkv_b=d_qkv_b,
        d_sout_w=p.blocks(dd, "self_attn.out.weight"),
        d_sout_b=p.blocks(dd, "self_attn.out.bias"),
        d_ln1=p.ln_blocks(dd, "ln1"),
        d_q_w=p.blocks(dd, "cross_attn.q.weight"),
        d_q_b=p.blocks(dd, "cross_attn.q.bias"),
        d_kv_w=p.fused(dd, ("cross_attn.k", "cross_attn.v"), "weight"),
        d_kv_b=p.fused(dd, ("cross_attn.k", "cross_attn.v"), "bias"),
        d_cout_w=p.blocks(dd, "cross_attn.out.weight"),
        d_cout_b=p.blocks(dd, "cross_attn.out.bias"),
        d_ln2=p.ln_blocks(dd, "ln2"),
        d_fc1_w=p.blocks(dd, "mlp.0.weight"),
        d_fc1_b=p.blocks(dd, "mlp.0.bias"),
        d_fc2_w=p.blocks(dd, "mlp.2.weight"),
        d_fc2_b=p.blocks(dd, "mlp.2.bias"),
        d_ln3=p.ln_blocks(dd, "ln3"),
        h_w1=p["policy_head.0.weight"],
        h_b1=p["policy_head.0.bias"],
        h_ln=p.ln("policy_head.2"),
        h_w2=p["policy_head.3.weight"],
        h_b2=p["policy_head.3.bias"],
    )


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
    return (x - mean) / np.sqrt(var + LN_EPS) * weight + bias
