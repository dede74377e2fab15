"""Line-of-sight sensing: the ray table of the 7x7 forward view and the per-world sense kernel.

A robot sees the cells of its own row (3 each side) and the 6 rows ahead. A cell is visible iff the
segment from the robot's cell centre to the cell's centre crosses the interior of no opaque cell (walls,
obstacles) before it; a segment that passes exactly through a lattice corner is blocked only when both
cells pinching that corner are opaque. The table is computed once, exactly (rational arithmetic), in the
robot frame (forward ``f``, rightward ``l``) and rotated by the heading at run time.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np
from numba import njit

from catmip_env.config import VIEW_SIZE
from catmip_env.constants import (
    CLUE,
    CLUE_BIT,
    EXPLORED,
    OBSTACLE,
    OCCUPIED,
    TARGET,
    TARGET_BIT,
    WALL,
)

__all__ = [
    "view_cells",
    "RAY_CELLS",
    "RAY_BLOCKERS",
    "RAY_NBLOCK",
    "VIEW_OFFSETS",
    "VIEW_BLOCKERS",
    "to_world",
    "sense_robot",
]


def _open_square_hit(f: int, l: int, a: int, b: int) -> bool:
    """Does the segment (0,0)->(f,l) cross the open unit square centred on (a, b)?"""
    t0, t1 = Fraction(0), Fraction(1)
    for d, c in ((f, a), (l, b)):
        lo, hi = Fraction(2 * c - 1, 2), Fraction(2 * c + 1, 2)
        if d == 0:
            if not lo < 0 < hi:
                return False
            continue
        ta, tb = lo / d, hi / d
        if ta > tb:
            ta, tb = tb, ta
        t0, t1 = max(t0, ta), min(t1, tb)
    return t0 < t1


def _corner_pinches(f: int, l: int) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """Pairs of cells whose shared corner the open segment passes through exactly."""
    pinches = []
    if f == 0 or l == 0:
        return pinches
    for a in range(min(0, f) - 1, max(0, f) + 1):
        for b in range(min(0, l) - 1, max(0, l) + 1):
            # Corner point (a + 1/2, b + 1/2) lies on the segment iff it is a multiple of (f, l).
            x, y = Fraction(2 * a + 1, 2), Fraction(2 * b + 1, 2)
            t = x / f
            if 0 < t < 1 and y == t * l:
                quad = [(a, b), (a + 1, b), (a, b + 1), (a + 1, b + 1)]
                side = [q for q in quad if not _open_square_hit(f, l, *q)]
                if len(side) == 2:
                    pinches.append((side[0], side[1]))
    return pinches


def view_cells(view: int = VIEW_SIZE) -> list[tuple[int, int]]:
    """(forward, rightward) offsets of the view: own row and ``view - 1`` rows ahead."""
    half = view // 2
    return [(f, l) for f in range(view) for l in range(-half, half + 1)]


def _build_table(view: int = VIEW_SIZE) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    cells = view_cells(view)
    rays = []
    for f, l in cells:
        blockers = []
        if (f, l) != (0, 0):
            for a in range(min(0, f), max(0, f) + 1):
                for b in range(min(0, l), max(0, l) + 1):
                    if (a, b) in ((0, 0), (f, l)):
                        continue
                    if _open_square_hit(f, l, a, b):
                        blockers.append((a, b, a, b))
            for (a1, b1), (a2, b2) in _corner_pinches(f, l):
                blockers.append((a1, b1, a2, b2))
        rays.append(blockers)
    nmax = max(1, max(len(r) for r in rays))
    table = np.zeros((len(cells), nmax, 4), dtype=np.int64)
    nblock = np.zeros(len(cells), dtype=np.int64)
    for k, r in enumerate(rays):
        nblock[k] = len(r)
        for j, blk in enumerate(r):
            table[k, j] = blk
    return np.array(cells, dtype=np.int64), table, nblock


RAY_CELLS, RAY_BLOCKERS, RAY_NBLOCK = _build_table()


def _rotate(f: np.ndarray, l: np.ndarray, heading: int) -> tuple[np.ndarray, np.ndarray]:
    """Robot-frame (forward, rightward) -> world (drow, dcol) for a heading (E, S, W, N)."""
    return {0: (l, f), 1: (f, -l), 2: (-l, -f), 3: (-f, l)}[heading]


def _world_tables() -> tuple[np.ndarray, np.ndarray]:
    """The ray table rotated to every heading: cell offsets (4, K, 2) and blocker offsets
    (4, K, M, 4) as (drow1, dcol1, drow2, dcol2); a single blocker repeats its cell."""
    cells = np.zeros((4,) + RAY_CELLS.shape, np.int64)
    blockers = np.zeros((4,) + RAY_BLOCKERS.shape, np.int64)
    for h in range(4):
        cells[h, :, 0], cells[h, :, 1] = _rotate(RAY_CELLS[:, 0], RAY_CELLS[:, 1], h)
        for j in (0, 2):
            dr, dc = _rotate(RAY_BLOCKERS[..., j], RAY_BLOCKERS[..., j + 1], h)
            blockers[h, ..., j], blockers[h, ..., j + 1] = dr, dc
    return cells, blockers


VIEW_OFFSETS, VIEW_BLOCKERS = _world_tables()


@njit(cache=True, inline="always")
def to_world(r: int, c: int, heading: int, f: int, l: int) -> tuple[int, int]:
    """Robot-frame offset (forward f, rightward l) -> world cell, for headings E, S, W, N."""
    if heading == 0:
        return r + l, c + f
    if heading == 1:
        return r + f, c - l
    if heading == 2:
        return r - l, c - f
    return r - f, c + l


@njit(cache=True, inline="always")
def _opaque(grid: np.ndarray, b: int, r: int, c: int) -> bool:
    if r < 0 or c < 0 or r >= grid.shape[1] or c >= grid.shape[2]:
        return True
    g = grid[b, r, c]
    return g == WALL or g == OBSTACLE


@njit(cache=True)
def sense_robot(
    grid: np.ndarray,  # (B, H, W) uint8 cell codes
    belief: np.ndarray,  # (B, N, H, W) uint8 belief bits
    b: int,
    i: int,
    r: int,
    c: int,
    heading: int,
    view_offsets: np.ndarray,  # (4, K, 2) VIEW_OFFSETS
    view_blockers: np.ndarray,  # (4, K, M, 4) VIEW_BLOCKERS
    ray_nblock: np.ndarray,  # (K,) RAY_NBLOCK
) -> None:
    """Mark every cell visible from (r, c, heading) as explored in robot i's belief."""
    h, w = grid.shape[1], grid.shape[2]
    offs = view_offsets[heading]
    blk = view_blockers[heading]
    for k in range(offs.shape[0]):
        rr, cc = r + offs[k, 0], c + offs[k, 1]
        if rr < 0 or cc < 0 or rr >= h or cc >= w:
            continue
        visible = True
        for j in range(ray_nblock[k]):
            if _opaque(grid, b, r + blk[k, j, 0], c + blk[k, j, 1]) and _opaque(
                grid, b, r + blk[k, j, 2], c + blk[k, j, 3]
            ):
                visible = False
                break
        if not visible:
            continue
        g = grid[b, rr, cc]
        bits = EXPLORED
        if g == WALL or g == OBSTACLE:
            bits |= OCCUPIED
        elif g == TARGET:
            bits |= OCCUPIED | TARGET_BIT
        elif g == CLUE:
            bits |= CLUE_BIT
        belief[b, i, rr, cc] |= bits
