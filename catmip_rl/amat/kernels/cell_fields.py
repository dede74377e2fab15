"""Per-cell inputs of the cell-goal AMAT (``amat.pointer``), computed from the macro-observation alone.

A robot knows its own map, so it can compute what the planners compute from it: its position (the
centre of its 3x3 own-position stamp) and the path distance from there to every cell over its
occupancy channel (unknown cells free, the map's outer ring wall, as the low-level controller plans).
Other robots are not obstacles here: the observation shows them as 3x3 blocks, not cells.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from catmip_env.constants import OBS_ONE
from catmip_env.kernels.bfs import bfs_from

__all__ = ["cell_fields"]


@njit(cache=True, nogil=True)
def _fields(gmap: np.ndarray, pos: np.ndarray, dist: np.ndarray) -> None:
    """gmap (M, 5+C, H, W) uint8 -> pos (M, 2) int64 and dist (M, H, W) int16 (-1: unreachable)."""
    m, ch, h, w = gmap.shape
    own = ch - 1  # the own-position channel, last of the global map
    blocked = np.zeros((h, w), np.bool_)
    flat = np.empty(h * w, np.int64)
    queue = np.empty(h * w, np.int64)
    for k in range(m):
        r_lo, r_hi, c_lo, c_hi = h, -1, w, -1
        for r in range(h):
            for c in range(w):
                if gmap[k, own, r, c] == OBS_ONE:
                    r_lo, r_hi = min(r_lo, r), max(r_hi, r)
                    c_lo, c_hi = min(c_lo, c), max(c_hi, c)
                blocked[r, c] = gmap[k, 1, r, c] >= OBS_ONE
        if r_hi < 0:  # padding: no robot on this map
            pos[k, 0], pos[k, 1] = -1, -1
            dist[k] = -1
            continue
        r0, c0 = (r_lo + r_hi) // 2, (c_lo + c_hi) // 2
        pos[k, 0], pos[k, 1] = r0, c0
        blocked[0, :] = True
        blocked[h - 1, :] = True
        blocked[:, 0] = True
        blocked[:, w - 1] = True
        blocked[r0, c0] = False
        bfs_from(blocked, r0, c0, flat, queue, -1)
        for r in range(h):
            for c in range(w):
                dist[k, r, c] = flat[r * w + c]


def cell_fields(global_map: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``global_map`` (..., 5+C, H, W) uint8 -> (own cell (..., 2) int64, path distance (..., H, W)
    int16 with -1 where unreachable). A map without an own-position stamp (padding) gives -1s."""
    lead, (ch, h, w) = global_map.shape[:-3], global_map.shape[-3:]
    flat = np.ascontiguousarray(global_map).reshape(-1, ch, h, w)
    pos = np.empty((len(flat), 2), np.int64)
    dist = np.empty((len(flat), h, w), np.int16)
    _fields(flat, pos, dist)
    return pos.reshape(*lead, 2), dist.reshape(*lead, h, w)
