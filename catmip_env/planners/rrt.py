"""The RRT planner's kernels (``catmip_env.planners.RRT``): its tree, grown over a robot's known free space,
returns the cells of unexplored space that it reached (exploration targets); those cells' 8-connected
clusters (:func:`label8`, APF's too) and each cluster's goal and score (:func:`cluster_goals`)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["grow_rrt", "label8", "cluster_goals"]


@njit(cache=True)
def grow_rrt(
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
    # bucket grid for nearest-node queries: per cell, a linked list of nodes; box: the occupied buckets'
    # bounding box (rows rmin..rmax, columns cmin..cmax), outside which the search skips the empty cells
    head = np.full(h * w, -1, np.int64)
    nxt = np.full(n_iter + 1, -1, np.int64)
    box = np.empty(4, np.int64)
    box[0] = box[1] = int(r0 + 0.5)
    box[2] = box[3] = int(c0 + 0.5)
    head[box[0] * w + box[2]] = 0
    for it in range(n_iter):
        sr, sc = u[it, 0] * h - 0.5, u[it, 1] * w - 0.5
        best, best_d2 = _nearest_node(nodes, head, nxt, box, w, sr, sc)
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
        box[0], box[1] = min(box[0], gr), max(box[1], gr)
        box[2], box[3] = min(box[2], gc), max(box[3], gc)
        nxt[n_nodes] = head[cell]
        head[cell] = n_nodes
        n_nodes += 1
    return n_targets


@njit(cache=True)
def _nearest_node(nodes, head, nxt, box, w, sr, sc):
    """The tree node for the sample (sr, sc), by rings of buckets around the sample's cell (cr, cc), and
    its squared distance. A node of the sample's own cell within one cell is taken (the planner's rule:
    a near node, not always the nearest). Further out the search is exact: the sample lies within half
    a cell of (cr, cc) and a node within half a cell of its bucket's centre, so every node of the next
    ring is more than ``ring`` away. Rings short of the bounding box ``box`` hold no node and are skipped."""
    h = head.shape[0] // w
    cr, cc = min(max(int(sr + 0.5), 0), h - 1), min(max(int(sc + 0.5), 0), w - 1)
    rmin, rmax, cmin, cmax = box[0], box[1], box[2], box[3]
    best, best_d2 = -1, 1e18
    ring = max(0, rmin - cr, cr - rmax, cmin - cc, cc - cmax)
    while ring < h + w:
        for rr in range(max(cr - ring, rmin), min(cr + ring, rmax) + 1):
            edge = abs(rr - cr) == ring  # the ring's top or bottom row: all its columns, else its two ends
            c2 = max(cc - ring, cmin) if edge else cc - ring
            last = min(cc + ring, cmax) if edge else cc + ring
            while c2 <= last:
                if cmin <= c2 <= cmax:
                    k = head[rr * w + c2]
                    while k >= 0:
                        d2 = (nodes[k, 0] - sr) ** 2 + (nodes[k, 1] - sc) ** 2
                        if d2 < best_d2:
                            best, best_d2 = k, d2
                        k = nxt[k]
                c2 += 1 if edge else 2 * ring
        if best >= 0 and (ring * ring >= best_d2 or (ring == 0 and best_d2 <= 1.0)):
            break
        ring += 1
    return best, best_d2


@njit(cache=True)
def label8(mask: np.ndarray) -> tuple[np.ndarray, int]:
    """8-connected component labels (H, W) int64 (1..K, 0 outside ``mask``) and K, numbered in the raster
    order of each component's first cell."""
    h, w = mask.shape
    labels = np.zeros((h, w), np.int64)
    stack = np.empty(h * w, np.int64)
    k = 0
    for r in range(h):
        for c in range(w):
            if not mask[r, c] or labels[r, c]:
                continue
            k += 1
            labels[r, c] = k
            stack[0], top = r * w + c, 1
            while top:
                top -= 1
                y, x = divmod(stack[top], w)
                for yy in range(max(y - 1, 0), min(y + 2, h)):
                    for xx in range(max(x - 1, 0), min(x + 2, w)):
                        if mask[yy, xx] and not labels[yy, xx]:
                            labels[yy, xx] = k
                            stack[top] = yy * w + xx
                            top += 1
    return labels, k


@njit(cache=True)
def cluster_goals(cells: np.ndarray, counts: np.ndarray, dist: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(K, 3) float64 (row, column, score) of the clusters of ``cells`` (:func:`label8`'s order) that hold a
    reachable valid cell: of those cells, the one nearest their mean (the first in raster order on a tie),
    scored ``counts`` there minus its path distance ``dist`` over the farthest reachable one's."""
    h, w = cells.shape
    labels, k = label8(cells)
    far = 1
    for r in range(h):
        for c in range(w):
            far = max(far, dist[r, c])
    n, sr, sc = np.zeros(k + 1, np.int64), np.zeros(k + 1), np.zeros(k + 1)
    for r in range(h):
        for c in range(w):
            if labels[r, c] and dist[r, c] >= 0 and valid[r, c]:
                n[labels[r, c]] += 1
                sr[labels[r, c]] += r
                sc[labels[r, c]] += c
    best, best_d2 = np.full(k + 1, -1, np.int64), np.full(k + 1, np.inf)
    for r in range(h):
        for c in range(w):
            j = labels[r, c]
            if j and dist[r, c] >= 0 and valid[r, c]:
                d2 = (r - sr[j] / n[j]) ** 2 + (c - sc[j] / n[j]) ** 2
                if d2 < best_d2[j]:
                    best[j], best_d2[j] = r * w + c, d2
    out = np.empty((k, 3))
    m = 0
    for j in range(1, k + 1):
        if n[j]:
            r, c = divmod(best[j], w)
            out[m, 0], out[m, 1], out[m, 2] = r, c, counts[r, c] - dist[r, c] / far
            m += 1
    return out[:m]
