"""Shortest paths on belief maps: BFS on a 4-connected grid with unit costs.

The controller that uses them: docs/design.md#low-level-controller.

Unknown cells count as free; cells whose used occupancy is set and cells with another robot are
blocked. BFS gives the same path lengths as A* with the Manhattan heuristic. Scratch buffers are
passed in so that the per-tick controller allocates nothing.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from catmip_env.constants import STEP_COL, STEP_ROW

UNREACHED = -1


@njit(cache=True)
def bfs_from(
    blocked: np.ndarray,  # (H, W) bool
    r0: int,
    c0: int,
    dist: np.ndarray,  # (H * W) int64 scratch/out: distance from (r0, c0), -1 unreached
    queue: np.ndarray,  # (H * W) int64 scratch
    stop: int,  # flat cell index at which to stop early (-1: full field)
) -> int:
    """Distance field from (r0, c0) over unblocked cells (the start itself may be blocked: it is
    expanded anyway only if unblocked). Returns dist[stop] (or -1), or the number of cells reached."""
    h, w = blocked.shape
    dist[:] = UNREACHED
    if blocked[r0, c0]:
        return UNREACHED if stop >= 0 else 0
    s = r0 * w + c0
    dist[s] = 0
    queue[0] = s
    head, tail = 0, 1
    while head < tail:
        k = queue[head]
        head += 1
        if k == stop:
            return dist[k]
        r, c = k // w, k % w
        d = dist[k] + 1
        for m in range(4):
            rr, cc = r + STEP_ROW[m], c + STEP_COL[m]
            if 0 <= rr < h and 0 <= cc < w:
                kk = rr * w + cc
                if dist[kk] == UNREACHED and not blocked[rr, cc]:
                    dist[kk] = d
                    queue[tail] = kk
                    tail += 1
    return UNREACHED if stop >= 0 else tail


@njit(cache=True)
def next_step(
    blocked: np.ndarray,  # (H, W) bool; the robot's own cell must be False
    r: int,
    c: int,
    heading: int,
    gr: int,
    gc: int,
    dist: np.ndarray,
    queue: np.ndarray,
) -> int:
    """Direction (0..3) of the first move of a shortest path from (r, c) to (gr, gc); -1 if the goal is
    unreachable, 4 if already there. Among equally short first moves the current heading wins, then
    the order E, S, W, N."""
    if r == gr and c == gc:
        return 4
    w = blocked.shape[1]
    d = bfs_from(blocked, gr, gc, dist, queue, r * w + c)
    if d == UNREACHED:
        return -1
    return downhill(dist, blocked.shape[0], w, r, c, heading, d)


@njit(cache=True)
def downhill(dist: np.ndarray, h: int, w: int, r: int, c: int, heading: int, d: int) -> int:
    """Direction (0..3) of a move from (r, c), at distance ``d`` in the field ``dist`` (flat, (H * W)),
    to a neighbour at ``d - 1``: the current heading first, then E, S, W, N (``heading`` -1: no
    heading, E, S, W, N only); -1 if there is none."""
    for m in range(0 if heading >= 0 else 1, 5):
        mm = heading if m == 0 else m - 1  # the current heading first, then E, S, W, N
        if m > 0 and mm == heading:
            continue
        rr, cc = r + STEP_ROW[mm], c + STEP_COL[mm]
        if 0 <= rr < h and 0 <= cc < w and dist[rr * w + cc] == d - 1:
            return mm
    return -1  # none (never for next_step: its BFS reached the robot, so a predecessor exists)
