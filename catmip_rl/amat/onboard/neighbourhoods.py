"""One communication neighbourhood's decision, as its robots make it (docs/design.md#distributed-execution):
every robot embeds its own macro-observation and sends a d-float token; the coordinator of each
neighbourhood (its lowest id) runs encoder + decoder on the members' tokens only and sends each active
member its goal. :func:`decide_neighbourhoods` does it for a batch of worlds (the executors'
decisions, ``catmip_rl.amat.onboard.execution``), :func:`decide_by_neighbourhood` on one world's
tensors, and the helpers below one neighbourhood by hand.

>>> token = embed_robot(model, obs, i)                  # on robot i: (d,)
>>> goals = coordinate(model, tokens, classes, masks, active)   # on the coordinator
>>> message_bytes(model.config, map_shape=(20, 20))    # embedding vs raw macro-observation
"""

from __future__ import annotations

import numpy as np
import torch

from catmip_rl.amat.config import AmatConfig
from catmip_rl.amat.inputs import macro_observation
from catmip_rl.amat.model import AMAT, decision_order
from catmip_rl.amat.onboard.fast_amat import FastAmat

__all__ = [
    "GOAL_BYTES",
    "embed_robot",
    "coordinate",
    "message_bytes",
    "decide_neighbourhoods",
    "decide_neighbourhoods_fast",
    "active_neighbourhoods",
    "decide_by_neighbourhood",
]

GOAL_BYTES = 2
"""A goal message: the window index (D^2 <= 65,536) as an unsigned 16-bit integer."""


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
    """Goals (N,) of one world decided neighbourhood by neighbourhood (busy robots: their first valid
    action): :func:`decide_neighbourhoods` (what :class:`AmatExecutor` runs) on a batch of one world."""
    labels = neighbourhood.numpy()
    lowest = np.array([np.flatnonzero(labels == label)[0] for label in labels], np.int64)
    actions, _, _ = decide_neighbourhoods(
        model,
        obs["global_map"].numpy()[None],
        obs["local_map"].numpy()[None],
        obs["agent_class"].argmax(-1).numpy()[None],
        action_mask.numpy()[None],
        active.numpy().astype(np.bool_)[None],
        lowest[None],
        stay_action=action_mask.shape[-1] // 2,  # the window's centre
        deterministic=deterministic,
    )
    return torch.from_numpy(actions[0])


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


@torch.no_grad()
def decide_neighbourhoods(
    model: AMAT,
    global_map: np.ndarray,  # (B, N, 5+C, H, W) uint8 macro-observations
    local_map: np.ndarray,  # (B, N, 4+C, L, L) uint8
    cls: np.ndarray,  # (B, N) int class index
    masks: np.ndarray,  # (B, N, A) action masks
    active: np.ndarray,  # (B, N) bool robots that decide now
    comp: np.ndarray,  # (B, N) int neighbourhood label = its lowest robot id
    stay_action: int,
    deterministic: bool = True,
    generator: torch.Generator | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The decisions of every neighbourhood with an active robot, each on its members' tokens only
    (encoder + decoder on one padded row per neighbourhood: other rows' robots are invisible):
    (actions (B, N) int64 (inactive robots: their first valid action), the world of each decided
    neighbourhood (R,), its members (R, N) bool)."""
    b, n = active.shape
    actions = masks.argmax(-1).astype(np.int64)
    if not active.any():
        return actions, np.zeros(0, np.int64), np.zeros((0, n), np.bool_)
    b_of_row, member = active_neighbourhoods(active, comp)
    r = len(b_of_row)
    slot = np.cumsum(member, axis=1) - 1  # position of each member inside its row
    row_idx, robot = np.nonzero(member)
    pos = slot[row_idx, robot]
    world = b_of_row[row_idx]
    # every member embeds its own macro-observation (robots of other neighbourhoods need not)
    c = model.config.n_classes
    obs = macro_observation(
        global_map[world, robot][None], local_map[world, robot][None], cls[world, robot][None], c
    )
    tokens = model.embed(obs)[0]  # (K, d)
    tok = tokens.new_zeros(r, n, tokens.shape[-1])
    tok[row_idx, pos] = tokens
    padding = torch.ones(r, n, dtype=torch.bool)
    padding[row_idx, pos] = False
    act_rows = torch.zeros(r, n, dtype=torch.bool)
    act_rows[row_idx, pos] = torch.from_numpy(active[world, robot])
    mask_rows = torch.zeros(r, n, masks.shape[-1], dtype=torch.bool)
    mask_rows[:, :, stay_action] = True  # padding slots: any single valid entry
    mask_rows[row_idx, pos] = torch.from_numpy(masks[world, robot].astype(np.bool_))
    cls_rows = torch.zeros(r, n, c)
    cls_rows[row_idx, pos] = obs["agent_class"][0]
    rep, _ = model.encode(tok, key_padding_mask=padding)
    order = decision_order(act_rows, padding)
    a, _ = model.decode_autoregressive(
        rep,
        mask_rows,
        order,
        act_rows,
        cls_rows,
        deterministic=deterministic,
        generator=generator,
    )
    chosen = a[row_idx, pos].numpy()
    is_active = act_rows[row_idx, pos].numpy()
    actions[world[is_active], robot[is_active]] = chosen[is_active]
    return actions, b_of_row, member


def active_neighbourhoods(active: np.ndarray, comp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The neighbourhoods that decide at an event: one row per (world, component label = its lowest
    robot id) with an active member, in world then label order: (world of each row (R,), its members
    (R, N) bool, ascending id)."""
    b, n = active.shape
    bb, ii = np.nonzero(active)
    has_active = np.zeros((b, n), np.bool_)
    has_active[bb, comp[bb, ii]] = True
    b_of_row, label = np.nonzero(has_active)
    return b_of_row, comp[b_of_row] == label[:, None]


def decide_neighbourhoods_fast(
    fast: FastAmat,
    global_map: np.ndarray,
    local_map: np.ndarray,
    cls: np.ndarray,
    masks: np.ndarray,
    active: np.ndarray,
    comp: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`decide_neighbourhoods` with argmax actions, each neighbourhood decided at batch 1 by
    ``fast`` (the batch-1 runtime, as a coordinator runs it): the same actions and rows in the same
    order, without padding every neighbourhood to the team's size."""
    actions = masks.argmax(-1).astype(np.int64)
    b_of_row, member = active_neighbourhoods(active, comp)
    for w, m in zip(b_of_row, member):
        ids, act = np.flatnonzero(m), active[w][m]
        chosen, _, _ = fast.decide(
            global_map[w][m], local_map[w][m], cls[w][m], masks[w][m].astype(np.bool_), act
        )
        actions[w, ids[act]] = chosen[act]
    return actions, b_of_row, member
