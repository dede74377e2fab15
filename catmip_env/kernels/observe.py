"""Macro-observation builder (docs/design.md#observations), shared by the primitive and the macro level.

Per robot, from its own merged belief, as uint8 with ``float = uint8 * OBS_SCALE`` (1.0 -> 4,
clue 0.25 -> 1):

* ``global_map (5 + C, H, W)``: explored, occupied, target (3x3 block) / clues (0.25), own goal,
  other robots of each class in the robot's neighbourhood (3x3 blocks), own position (3x3 block).
* ``local_map (4 + C, L, L)`` centred on the robot, single cells, outside the map explored + occupied.

With ``memory`` (``EnvConfig.teammate_memory``) the global map's class channels also show each teammate
outside the neighbourhood at the cell where the robot last had news of it (``comms.remember``), as a
3x3 block of 0.5 — or 0.25 when the robot knows the target and that teammate did not know it then
(news it has not heard from this robot's side). Neighbours (1.0) are drawn over remembered teammates.

``occupied`` is the occupancy the robot uses this tick (noisy under SLAM noise).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from catmip_env.constants import (
    CH_CLASS0,
    CH_EXPLORED,
    CH_GOAL,
    CH_OCCUPIED,
    CH_TARGET,
    CLUE_BIT,
    EXPLORED,
    OBS_CLUE,
    OBS_HALF,
    OBS_ONE,
    OCCUPIED,
    TARGET_BIT,
)

# The branch-free channel loops below turn belief bits into observation values by shifting.
assert EXPLORED << 2 == OBS_ONE and OCCUPIED << 1 == OBS_ONE and CLUE_BIT >> 2 == OBS_CLUE


@njit(cache=True, inline="always")
def _stamp3(obs: np.ndarray, b: int, i: int, ch: int, r: int, c: int, v: int = OBS_ONE) -> None:
    """A 3x3 block of value ``v`` (1.0 by default) that keeps any larger value already there."""
    h, w = obs.shape[3], obs.shape[4]
    for rr in range(max(r - 1, 0), min(r + 2, h)):
        for cc in range(max(c - 1, 0), min(c + 2, w)):
            obs[b, i, ch, rr, cc] = max(obs[b, i, ch, rr, cc], v)


@njit(cache=True, inline="always")
def _teammates(obs_global, b, i, knows, pos, cls, comp, memory, heard_tick, heard_pos, heard_knows) -> None:
    """Robot i's teammates on its global map: those of its neighbourhood (1.0) and, with ``memory``, the
    others where it last had news of them (0.5; 0.25 for one that did not know the target i knows)."""
    for j in range(cls.shape[1]):
        if j == i:
            continue
        if comp[b, j] == comp[b, i]:
            _stamp3(obs_global, b, i, CH_CLASS0 + cls[b, j], pos[b, j, 0], pos[b, j, 1])
        elif memory and heard_tick[b, i, j] >= 0:
            v = OBS_CLUE if knows and not heard_knows[b, i, j] else OBS_HALF
            r, c = heard_pos[b, i, j, 0], heard_pos[b, i, j, 1]
            _stamp3(obs_global, b, i, CH_CLASS0 + cls[b, j], r, c, v)


@njit(cache=True, nogil=True)  # threads=: chunks of worlds run at once
def observe(
    worlds: np.ndarray,  # (B,) bool: build observations for these worlds
    belief: np.ndarray,  # (B, N, H, W) uint8
    used_occ: np.ndarray,  # (B, N, H, W) uint8, read when noisy
    noisy: bool,
    pos: np.ndarray,  # (B, N, 2)
    cls: np.ndarray,  # (B, N) class index
    comp: np.ndarray,  # (B, N) neighbourhood label
    goal: np.ndarray,  # (B, N, 2), row -1 = no goal
    target: np.ndarray,  # (B, 2)
    obs_global: np.ndarray,  # (B, N, 5 + C, H, W) uint8 out
    obs_local: np.ndarray,  # (B, N, 4 + C, L, L) uint8 out
    memory: bool,  # show remembered teammates (EnvConfig.teammate_memory)
    heard_tick: np.ndarray,  # (B, N, N) int64, -1 = no news
    heard_pos: np.ndarray,  # (B, N, N, 2) int64
    heard_knows: np.ndarray,  # (B, N, N) bool
) -> None:
    n, h, w = belief.shape[1], belief.shape[2], belief.shape[3]
    hw = h * w
    n_cls = obs_local.shape[2] - 4
    for b in range(worlds.shape[0]):
        if not worlds[b]:
            continue
        tr, tc = target[b, 0], target[b, 1]
        for i in range(n):
            # -- global map: belief channels (branch-free flat loops) -------------------------
            bel = belief[b, i].reshape(hw)
            g_exp = obs_global[b, i, CH_EXPLORED].reshape(hw)
            g_occ = obs_global[b, i, CH_OCCUPIED].reshape(hw)
            g_tgt = obs_global[b, i, CH_TARGET].reshape(hw)
            for k in range(hw):
                v = bel[k]
                g_exp[k] = (v & EXPLORED) << 2  # 1.0 -> 4
                g_tgt[k] = (v & CLUE_BIT) >> 2  # 0.25 -> 1
            if noisy:
                occ = used_occ[b, i].reshape(hw)
                for k in range(hw):
                    g_occ[k] = occ[k] << 2
            else:
                for k in range(hw):
                    g_occ[k] = (bel[k] & OCCUPIED) << 1
            obs_global[b, i, CH_GOAL:] = 0
            knows = (belief[b, i, tr, tc] & TARGET_BIT) != 0
            if knows:
                _stamp3(obs_global, b, i, CH_TARGET, tr, tc)
            gr, gc = goal[b, i, 0], goal[b, i, 1]
            if gr >= 0:
                obs_global[b, i, CH_GOAL, gr, gc] = OBS_ONE
            _teammates(obs_global, b, i, knows, pos, cls, comp, memory, heard_tick, heard_pos, heard_knows)
            _stamp3(obs_global, b, i, CH_CLASS0 + n_cls, pos[b, i, 0], pos[b, i, 1])
            _local_map(b, i, belief, pos, cls, comp, goal, obs_global, obs_local)


@njit(cache=True, inline="always")
def _local_map(b, i, belief, pos, cls, comp, goal, obs_global, obs_local) -> None:
    """Robot i's local map, centred on it: explored and occupied copied from its global map (both set
    outside the map), target / clue, own goal, the robots of its neighbourhood by class."""
    n, h, w = belief.shape[1], belief.shape[2], belief.shape[3]
    n_cls = obs_local.shape[2] - CH_CLASS0
    half = obs_local.shape[3] // 2
    gr, gc = goal[b, i, 0], goal[b, i, 1]
    r0, c0 = pos[b, i, 0] - half, pos[b, i, 1] - half
    size = 2 * half + 1
    for lr in range(size):
        r = r0 + lr
        for lc in range(size):
            c = c0 + lc
            for ch in range(CH_CLASS0 + n_cls):
                obs_local[b, i, ch, lr, lc] = 0
            if r < 0 or c < 0 or r >= h or c >= w:
                obs_local[b, i, CH_EXPLORED, lr, lc] = OBS_ONE
                obs_local[b, i, CH_OCCUPIED, lr, lc] = OBS_ONE
                continue
            obs_local[b, i, CH_EXPLORED, lr, lc] = obs_global[b, i, CH_EXPLORED, r, c]
            obs_local[b, i, CH_OCCUPIED, lr, lc] = obs_global[b, i, CH_OCCUPIED, r, c]
            v = belief[b, i, r, c]
            if v & TARGET_BIT:
                obs_local[b, i, CH_TARGET, lr, lc] = OBS_ONE
            elif v & CLUE_BIT:
                obs_local[b, i, CH_TARGET, lr, lc] = OBS_CLUE
            if r == gr and c == gc:
                obs_local[b, i, CH_GOAL, lr, lc] = OBS_ONE
    for j in range(n):
        if j != i and comp[b, j] == comp[b, i]:
            lr, lc = pos[b, j, 0] - r0, pos[b, j, 1] - c0
            if 0 <= lr < size and 0 <= lc < size:
                obs_local[b, i, CH_CLASS0 + cls[b, j], lr, lc] = OBS_ONE
