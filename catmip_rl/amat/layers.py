"""The transformer layers of AMAT (``model``): attention, MLP, encoder and decoder blocks, and
:class:`BlockCache`, a decoder block's cached keys/values for autoregressive decoding.

Shapes legend as in ``model``: ``B`` batch, ``T`` tokens, ``d`` embedding, ``h`` heads. The functional
helpers :func:`linear`, :func:`layer_norm` and :func:`stacked_linear` apply a layer's parameters without
the per-call overhead of ``nn.Module.__call__`` (``model`` uses them too, see ``AMAT.embed``).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from catmip_env.constants import OBS_SCALE  # uint8 macro-observations: float = value * OBS_SCALE
from catmip_rl.amat.kernels.small_attention import small_attention

__all__ = [
    "Attention",
    "MLP",
    "EncoderBlock",
    "DecoderBlock",
    "BlockCache",
    "linear",
    "layer_norm",
    "stacked_linear",
    "as_float",
]


def stacked_linear(layers: tuple[nn.Linear, ...]) -> tuple[torch.Tensor, torch.Tensor]:
    """(weight, bias) of linear layers on the same input, stacked along the output dimension."""
    return torch.cat([m.weight for m in layers]), torch.cat([m.bias for m in layers])


def linear(x: torch.Tensor, layer: nn.Linear) -> torch.Tensor:
    """``layer(x)`` without the module call."""
    return F.linear(x, layer.weight, layer.bias)


def layer_norm(x: torch.Tensor, layer: nn.LayerNorm) -> torch.Tensor:
    """``layer(x)`` without the module call."""
    return F.layer_norm(x, layer.normalized_shape, layer.weight, layer.bias, layer.eps)


def _heads(x: torch.Tensor, h: int) -> torch.Tensor:
    """(B, T, d) -> (B, h, T, d / h)."""
    b, t, d = x.shape
    return x.view(b, t, h, d // h).transpose(1, 2)


class Attention(nn.Module):
    """Multi-head attention with separate q / k / v / out projections (no dropout)."""

    def __init__(self, d: int, n_heads: int) -> None:
        super().__init__()
        self.n_heads = n_heads
        self.q, self.k, self.v, self.out = (nn.Linear(d, d) for _ in range(4))

    def split(self, x: torch.Tensor) -> torch.Tensor:  # (B, T, d) -> (B, h, T, d / h)
        b, t, d = x.shape
        return x.view(b, t, self.n_heads, d // self.n_heads).transpose(1, 2)

    def merge(self, x: torch.Tensor) -> torch.Tensor:  # (B, h, T, d / h) -> (B, T, d)
        b, h, t, dh = x.shape
        return x.transpose(1, 2).reshape(b, t, h * dh)

    def forward(
        self,
        query: torch.Tensor,
        key: torch.Tensor,
        value: torch.Tensor,
        allowed: torch.Tensor | None = None,
        rows: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """``allowed`` (B or 1, 1, Tq, Tk) bool: which keys each query may attend to. Projections of the
        same input are one matrix product (q/k/v of self-attention, k/v of cross-attention).

        ``rows`` (K,) long: flat indices into the B * Tq query rows; the output is then those rows
        only, (K, d), and the output projection runs on them alone."""
        d = query.shape[-1]
        if key is value:
            if query is key:
                lin = (self.q, self.k, self.v)
                q, k, v = F.linear(query, *stacked_linear(lin)).split(d, -1)
            else:
                q = self.q(query)
                k, v = F.linear(key, *stacked_linear((self.k, self.v))).split(d, -1)
        else:
            q, k, v = self.q(query), self.k(key), self.v(value)
        if q.dtype == torch.float32 and q.device.type == "cpu" and torch.is_grad_enabled():
            # training on CPU: a few tokens per event (catmip_rl.amat.kernels.small_attention)
            y = small_attention(q, k, v, allowed, self.n_heads)
        else:
            q, k, v = self.split(q), self.split(k), self.split(v)
            y = self.merge(F.scaled_dot_product_attention(q, k, v, attn_mask=allowed))
        return self.out(y if rows is None else y.flatten(0, 1)[rows])


class MLP(nn.Sequential):
    """The blocks' feed-forward layer: Linear(d, d), GELU, Linear(d, d)."""

    def __init__(self, d: int) -> None:
        """Width ``d`` in and out."""
        super().__init__(nn.Linear(d, d), nn.GELU(), nn.Linear(d, d))


class EncoderBlock(nn.Module):
    """A post-norm transformer encoder block: masked self-attention over the robots' tokens, then the
    MLP, each with a residual connection and LayerNorm."""

    def __init__(self, d: int, n_heads: int) -> None:
        """Width ``d``, ``n_heads`` attention heads."""
        super().__init__()
        self.attn = Attention(d, n_heads)
        self.ln1 = nn.LayerNorm(d)
        self.mlp = MLP(d)
        self.ln2 = nn.LayerNorm(d)

    def forward(
        self, x: torch.Tensor, allowed: torch.Tensor | None, rows: torch.Tensor | None = None
    ) -> torch.Tensor:
        """(B, T, d), or the flat rows ``rows`` of it (K, d): every token is a key, only they are queries."""
        h = self.attn(x, x, x, allowed, rows)
        x = self.ln1((x if rows is None else x.flatten(0, 1)[rows]) + h)
        return self.ln2(x + self.mlp(x))


class DecoderBlock(nn.Module):
    """A post-norm decoder block: causal self-attention over the actions decided so far, cross-attention
    from the encoder's representations to them, then the MLP, each with a residual and LayerNorm."""

    def __init__(self, d: int, n_heads: int) -> None:
        """Width ``d``, ``n_heads`` attention heads."""
        super().__init__()
        self.self_attn = Attention(d, n_heads)
        self.ln1 = nn.LayerNorm(d)
        self.cross_attn = Attention(d, n_heads)
        self.ln2 = nn.LayerNorm(d)
        self.mlp = MLP(d)
        self.ln3 = nn.LayerNorm(d)

    def fused_projections(self) -> tuple[torch.Tensor, ...]:
        """(W_qkv, b_qkv) of the self-attention and (W_kv, b_kv) of the cross-attention, concatenated
        for one matmul per decoding step (rebuilt per call: a few microseconds, and never stale)."""
        sa, ca = self.self_attn, self.cross_attn
        return (*stacked_linear((sa.q, sa.k, sa.v)), *stacked_linear((ca.k, ca.v)))

    def forward(
        self, x: torch.Tensor, rep: torch.Tensor, causal: torch.Tensor, rows: torch.Tensor | None = None
    ) -> torch.Tensor:
        """(B, T, d), or the flat rows ``rows`` of it (K, d) (every position is still a key)."""
        x = self.ln1(x + self.self_attn(x, x, x, causal))
        y = self.cross_attn(rep, x, x, causal, rows)  # query: encoder rep; key/value: actions
        x = self.ln2((rep if rows is None else rep.flatten(0, 1)[rows]) + y)
        return self.ln3(x + self.mlp(x))


class BlockCache:
    """Keys/values of one decoder block for the positions decoded so far (autoregressive mode).

    The step is written with functional calls and fused q/k/v weights: at batch 1 the decoder is a
    chain of tiny matmuls whose cost is mostly per-call overhead.
    """

    def __init__(self, block: DecoderBlock, rep_o: torch.Tensor) -> None:
        b, k, d = rep_o.shape
        sa, ca = block.self_attn, block.cross_attn
        self.block, self.rep_o, self.h, self.d = block, rep_o, sa.n_heads, d
        self.w_qkv, self.b_qkv, self.w_kv, self.b_kv = block.fused_projections()  # (3d, d), (2d, d)
        self.q_cross = _heads(linear(rep_o, ca.q), self.h)  # (B, h, K, dh): every position at once
        shape = (b, self.h, k, d // self.h)
        self.k_self, self.v_self = rep_o.new_empty(shape), rep_o.new_empty(shape)
        self.k_cross, self.v_cross = rep_o.new_empty(shape), rep_o.new_empty(shape)
        self.scale = (d // self.h) ** -0.5

    def _attend(self, q: torch.Tensor, keys: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
        w = torch.softmax((q @ keys.transpose(-1, -2)) * self.scale, -1)  # (B, h, 1, k+1)
        return (w @ values).transpose(1, 2).reshape(q.shape[0], 1, self.d)  # (B, 1, d)

    def step(self, x: torch.Tensor, k: int) -> torch.Tensor:
        """Block output (B, 1, d) at position k from its input x (B, 1, d)."""
        blk, h, d = self.block, self.h, self.d
        q, key, val = F.linear(x, self.w_qkv, self.b_qkv).split(d, -1)
        self.k_self[:, :, k : k + 1] = _heads(key, h)
        self.v_self[:, :, k : k + 1] = _heads(val, h)
        y = self._attend(_heads(q, h), self.k_self[:, :, : k + 1], self.v_self[:, :, : k + 1])
        x = layer_norm(x + linear(y, blk.self_attn.out), blk.ln1)
        key, val = F.linear(x, self.w_kv, self.b_kv).split(d, -1)
        self.k_cross[:, :, k : k + 1] = _heads(key, h)
        self.v_cross[:, :, k : k + 1] = _heads(val, h)
        y = self._attend(
            self.q_cross[:, :, k : k + 1], self.k_cross[:, :, : k + 1], self.v_cross[:, :, : k + 1]
        )
        x = layer_norm(self.rep_o[:, k : k + 1] + linear(y, blk.cross_attn.out), blk.ln2)
        m = blk.mlp
        return layer_norm(x + linear(F.gelu(linear(x, m[0])), m[2]), blk.ln3)


def as_float(x: torch.Tensor) -> torch.Tensor:
    """A macro-observation as float: uint8 scaled by OBS_SCALE, other dtypes cast."""
    if x.dtype == torch.uint8:
        return x.float() * OBS_SCALE
    return x.float() if not x.is_floating_point() else x
