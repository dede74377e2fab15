"""Distributed execution helpers (SPEC §8): every robot embeds its own macro-observation and sends a
d-float token; the coordinator of each neighbourhood (its lowest id) runs encoder + decoder on the
members' tokens only and sends each active member its goal.

>>> token = embed_robot(model, obs, i)                  # on robot i: (d,)
>>> goals = coordinate(model, tokens, classes, masks, active)   # on the coordinator
>>> message_bytes(model.config, map_shape=(20, 20))    # embedding vs raw macro-observation
"""

from __future__ import annotations

import torch

from catmip_rl.amat import AMAT, AmatConfig, decision_order

__all__ = ["embed_robot", "coordinate", "message_bytes", "decide_by_neighbourhood"]


@torch.no_grad()
def embed_robot(model: AMAT, obs: dict[str, torch.Tensor], i: int) -> torch.Tensor:
    """Robot i's token (d,) from a team observation dict with (N, ...) entries (no batch dim)."""
    one = {k: v[i : i + 1][None] for k, v in obs.items()}  # (1, 1, ...)
    return model.embed(one)[0, 0]


@torch.no_grad()
def coordinate(
    model: AMAT,
    tokens: torch.Tensor,  # (M, d) members' tokens, ascending robot id
    agent_class: torch.Tensor,  # (M, C)
    action_mask: torch.Tensor,  # (M, A)
    active: torch.Tensor,  # (M,) bool
    deterministic: bool = True,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Encoder + decoder over one neighbourhood's tokens: (actions (M,), log_probs (M,))."""
    rep, _ = model.encode(tokens[None])
    order = decision_order(active[None])
    a, lp = model.decode_autoregressive(
        rep, action_mask[None], order, active[None], agent_class[None], deterministic=deterministic
    )
    return a[0], lp[0]


@torch.no_grad()
def decide_by_neighbourhood(
    model: AMAT,
    obs: dict[str, torch.Tensor],  # (N, ...) entries of one world
    action_mask: torch.Tensor,  # (N, A)
    active: torch.Tensor,  # (N,) bool
    neighbourhood: torch.Tensor,  # (N,) long labels
    deterministic: bool = True,
) -> torch.Tensor:
    """Goals (N,) of one world decided neighbourhood by neighbourhood (busy robots: keep action)."""
    n = active.shape[0]
    tokens = torch.stack([embed_robot(model, obs, i) for i in range(n)])
    actions = action_mask.float().argmax(-1)
    for label in torch.unique(neighbourhood):
        members = torch.nonzero(neighbourhood == label)[:, 0]
        if not active[members].any():
            continue
        a, _ = coordinate(
            model, tokens[members], obs["agent_class"][members], action_mask[members], active[members],
            deterministic,
        )  # fmt: skip
        actions[members] = torch.where(active[members], a, actions[members])
    return actions


def message_bytes(config: AmatConfig, map_shape: tuple[int, int], float_bytes: int = 4) -> dict[str, int]:
    """Bytes one robot sends per decision: its embedding vs its raw macro-observation (float32 maps
    + class one-hot), and the raw maps stored as uint8."""
    h, w = map_shape
    l2 = config.local_size**2
    raw_values = config.global_channels * h * w + config.local_channels * l2
    return {
        "embedding": config.embed_dim * float_bytes,
        "raw_float32": (raw_values + config.n_classes) * float_bytes,
        "raw_uint8": raw_values + config.n_classes,
    }
