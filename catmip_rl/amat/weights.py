"""Weights between models: a coarse model's weights for a finer pooled global grid; a cell-goal model's
weights for the same model reading a planner's proposals (``AmatConfig.hint``)."""

from __future__ import annotations

import torch

__all__ = ["finer_pool", "with_hint"]


def finer_pool(state: dict[str, torch.Tensor], pool: int, new_pool: int) -> dict[str, torch.Tensor]:
    """``state`` (an AMAT state dict with pooled grid ``pool``) for a model whose grid is ``new_pool``,
    a multiple of it: each coarse cell's global LayerNorm weights are copied to the k x k fine cells it
    covers (k = new_pool / pool) and its ``obs_fc1`` input weights are split evenly among them. The two
    models agree wherever every fine k x k block of the pooled features repeats its coarse cell;
    elsewhere the fine model averages the fine cells where the coarse one read their maximum, so it
    is a starting point close to the coarse model, not the same function."""
    if new_pool % pool:
        raise ValueError(f"pool {new_pool} is not a multiple of {pool}: no cell-by-cell correspondence")
    k, out = new_pool // pool, dict(state)

    def spread(x: torch.Tensor) -> torch.Tensor:  # (..., G, G) -> (..., kG, kG)
        return x.repeat_interleave(k, dim=-2).repeat_interleave(k, dim=-1)

    for name in ("global_ln.weight", "global_ln.bias"):
        out[name] = spread(state[name])
    w, channels = state["obs_fc1.weight"], state["global_ln.weight"].shape[0]
    n_g = channels * pool * pool  # obs_fc1's input: the pooled global features, then the local ones
    w_g = spread(w[:, :n_g].reshape(w.shape[0], channels, pool, pool)) / (k * k)
    out["obs_fc1.weight"] = torch.cat([w_g.flatten(1), w[:, n_g:]], dim=1)
    return out


def with_hint(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """``state`` (a cell-goal AMAT's state dict without a hint) for the same model with one: the per-cell
    encoder's new input channel (the proposed cell, last) starts with zero weights and the proposed
    cell's logit bonus at zero, so the new model is the same function until training moves them."""
    out = dict(state)
    w = state["cell_in.weight"]  # (c, 7 + C, 3, 3)
    out["cell_in.weight"] = torch.cat([w, w.new_zeros(w.shape[0], 1, *w.shape[2:])], dim=1)
    out["hint_bias"] = w.new_zeros(1)
    return out
