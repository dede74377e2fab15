"""The RRT planner's tree (``catmip_env.planners.RRT``): grown over a robot's known free space, it
returns the cells of unexplored space that it reached (exploration targets)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["grow_rrt"]


@njit(cache=True)
def grow_rrt(  # noqa: C901 - numba kernel: one RRT loop nest
    explored: np.ndarray,  # (H, W) bool
    occupied: np.ndarray,  # (H, W) bool
    r0: float,
    c0: float,
    u: np.ndarray,  # (iterations, 2) uniforms
    step: float,
    max_targets: int,
    targets: np.ndarray,  # (max_targets, 2) int64 out
) -> int:
    """Grow an RRT from (r0, c0) over free explored space; returns the number of exploration targets
    (cells of unexplored space that the tree reached) written to ``targets``."""
    h, w = explored.shape
    n_iter = u.shape[0]
    nodes = np.empty((n_iter + 1, 2), np.float64)
    nodes[0, 0], nodes[0, 1] = r0, c0
    n_nodes, n_targets = 1, 0
    # bucket grid for nearest-node queries: per cell, a linked list of nodes
    head = np.full(h * w, -1, np.int64)
    nxt = np.full(n_iter + 1, -1, np.int64)
    head[int(r0 + 0.5) * w + int(c0 + 0.5)] = 0
    for it in range(n_iter):
        sr, sc = u[it, 0] * h - 0.5, u[it, 1] * w - 0.5
        cr, cc = min(max(int(sr + 0.5), 0), h - 1), min(max(int(sc + 0.5), 0), w - 1)
        best, best_d2 = -1, 1e18
        ring = 0
        while ring < h + w:
            for rr in range(cr - ring, cr + ring + 1):
                if rr < 0 or rr >= h:
                    continue
                for c2 in range(cc - ring, cc + ring + 1):
                    if c2 < 0 or c2 >= w or (abs(rr - cr) != ring and abs(c2 - cc) != ring):
                        continue
                    k = head[rr * w + c2]
                    while k >= 0:
                        d2 = (nodes[k, 0] - sr) ** 2 + (nodes[k, 1] - sc) ** 2
                        if d2 < best_d2:
                            best, best_d2 = k, d2
                        k = nxt[k]
            if best >= 0 and (ring - 1) ** 2 >= best_d2:
                break  # no node in a further ring can be closer
            ring += 1
        dist = math.sqrt(best_d2)
        if dist < 1e-9:
            continue
        f = min(step / dist, 1.0)
        nr = nodes[best, 0] + (sr - nodes[best, 0]) * f
        nc = nodes[best, 1] + (sc - nodes[best, 1]) * f
        gr, gc = int(nr + 0.5), int(nc + 0.5)
        if gr < 1 or gc < 1 or gr > h - 2 or gc > w - 2 or occupied[gr, gc]:
            continue
        if not explored[gr, gc]:
            targets[n_targets, 0], targets[n_targets, 1] = gr, gc
            n_targets += 1
            if n_targets >= max_targets:
                break
            continue
        nodes[n_nodes, 0], nodes[n_nodes, 1] = nr, nc
        cell = gr * w + gc
        nxt[n_nodes] = head[cell]
        head[cell] = n_nodes
        n_nodes += 1
    return n_targets
