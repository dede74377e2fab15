"""Shared test helpers for catmip_rl."""

import torch

from catmip_rl.amat.model import AMAT


def shaken_model(config=None, seed=0):
    """A model whose weights are far from the tiny-gain init, so that attention and the heads really mix."""
    torch.manual_seed(seed)
    m = AMAT(config)
    with torch.no_grad():
        for p in m.parameters():
            p.add_(0.2 * torch.randn_like(p))
    return m.eval()
