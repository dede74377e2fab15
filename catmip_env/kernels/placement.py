"""What a generated map holds besides its rooms: the robots in their spawn box, obstacles that cut nobody
off, and a target every robot can reach, with its clues (the rules: :mod:`~catmip_env.kernels.mapgen`)."""

from __future__ import annotations

import numpy as np
from numba import njit

from catmip_env.config import SPAWN_BOX
from catmip_env.constants import CLUE, FREE, OBSTACLE, STEPS, TARGET
from catmip_env.kernels.rng import block_choose, block_randint

__all__ = [
    "OUT_OF_UNIFORMS",
    "NO_SPAWN_ROOM",
    "NO_TARGET",
    "reachable_from",
    "place_robots",
    "place_obstacles_and_target",
]

# what a map kernel returns besides 0 (done)
OUT_OF_UNIFORMS = -1  # the block of uniforms ran out: draw again from a bigger block of the same stream
NO_SPAWN_ROOM = -2  # fewer free cells in the spawn box than robots
NO_TARGET = -3  # no target cell every robot reaches

_MAX_OBSTACLE_TRIES = 100
_MAX_TARGET_TRIES = 50


@njit(cache=True)
def reachable_from(passable: np.ndarray, r0: int, c0: int) -> np.ndarray:
    """4-connected flood fill over ``passable`` (H, W) bool from (r0, c0)."""
    h, w = passable.shape
    seen = np.zeros((h, w), dtype=np.bool_)
    queue = np.empty(h * w, dtype=np.int64)
    seen[r0, c0] = True
    queue[0] = r0 * w + c0
    head, tail = 0, 1
    while head < tail:
        k = queue[head]
        head += 1
        r, c = k // w, k % w
        for dr, dc in STEPS:
            rr, cc = r + dr, c + dc
            if 0 <= rr < h and 0 <= cc < w and passable[rr, cc] and not seen[rr, cc]:
                seen[rr, cc] = True
                queue[tail] = rr * w + cc
                tail += 1
    return seen


@njit(cache=True)
def place_robots(
    s: int,
    n: int,
    corner: int,
    u: np.ndarray,
    p: np.ndarray,
    grid: np.ndarray,
    robots: np.ndarray,
    headings: np.ndarray,
) -> int:
    """Robots on distinct free cells of the spawn box at ``corner``, uniform headings; 0 or an error code."""
    r0 = 1 if corner < 2 else s - 1 - SPAWN_BOX
    c0 = 1 if corner % 2 == 0 else s - 1 - SPAWN_BOX
    cells = np.empty(s * s, np.int64)
    count = 0
    for r in range(r0, r0 + SPAWN_BOX):
        for c in range(c0, c0 + SPAWN_BOX):
            if grid[r, c] == FREE:
                cells[count] = r * s + c
                count += 1
    if p[0] > u.shape[0]:
        return OUT_OF_UNIFORMS
    if count < n:
        return NO_SPAWN_ROOM
    block_choose(cells, count, n, u, p)
    for i in range(n):
        robots[i, 0], robots[i, 1] = cells[i] // s, cells[i] % s
    for i in range(n):
        headings[i] = block_randint(u, p, 4)
    return 0


@njit(cache=True)
def _draw_obstacles(
    base: np.ndarray,
    free: np.ndarray,
    n_obs: int,
    u: np.ndarray,
    p: np.ndarray,
    grid: np.ndarray,
    cells: np.ndarray,
) -> None:
    """``grid`` = ``base`` plus ``n_obs`` obstacles (fewer if short of room) on a uniform subset of the
    cells allowed by ``free`` (s, s) bool."""
    s = grid.shape[0]
    grid[:, :] = base
    count = 0
    for r in range(s):
        for c in range(s):
            if free[r, c]:
                cells[count] = r * s + c
                count += 1
    k = min(n_obs, count)
    block_choose(cells, count, k, u, p)
    for j in range(k):
        grid[cells[j] // s, cells[j] % s] = OBSTACLE


@njit(cache=True)
def _draw_target(
    allowed: np.ndarray,
    passable: np.ndarray,
    reach: np.ndarray,
    robots: np.ndarray,
    u: np.ndarray,
    p: np.ndarray,
    grid: np.ndarray,
    cells: np.ndarray,
    info: np.ndarray,
) -> int:
    """Draw the target among the ``allowed`` cells next to a ``reach``-able one until one cuts nobody
    off; writes it (and its clues) to ``grid`` and ``info[1:3]``. 0, or NO_TARGET / OUT_OF_UNIFORMS."""
    s, n = grid.shape[0], robots.shape[0]
    count = 0
    for r in range(1, s - 1):
        for c in range(1, s - 1):
            if allowed[r, c] and (reach[r - 1, c] or reach[r + 1, c] or reach[r, c - 1] or reach[r, c + 1]):
                cells[count] = r * s + c
                count += 1
    for _ in range(_MAX_TARGET_TRIES):
        if count == 0:
            break
        m = block_randint(u, p, count)
        tr, tc = cells[m] // s, cells[m] % s
        passable[tr, tc] = False  # the target is impassable: it must not cut anyone off
        reach2 = reachable_from(passable, robots[0, 0], robots[0, 1])
        passable[tr, tc] = True
        ok = reach2[tr - 1, tc] or reach2[tr + 1, tc] or reach2[tr, tc - 1] or reach2[tr, tc + 1]
        for i in range(n):
            ok &= reach2[robots[i, 0], robots[i, 1]]
        if ok:
            if p[0] > u.shape[0]:
                return OUT_OF_UNIFORMS
            grid[tr, tc] = TARGET
            for dr in range(-1, 2):
                for dc in range(-1, 2):
                    if grid[tr + dr, tc + dc] == FREE:
                        grid[tr + dr, tc + dc] = CLUE
            info[1], info[2] = tr, tc
            return 0
        count -= 1
        cells[m] = cells[count]
    return NO_TARGET


@njit(cache=True)
def place_obstacles_and_target(
    n_obs: int,
    excl_side: int,
    corner: int,
    zone: np.ndarray,
    u: np.ndarray,
    p: np.ndarray,
    grid: np.ndarray,
    robots: np.ndarray,
    info: np.ndarray,
) -> int:
    """Obstacles off doorway zones and robots, redrawn while they cut the team apart, then the target
    off doorway zones, robots and the exclusion box at the spawn corner. 0 or an error code."""
    s, n = grid.shape[0], robots.shape[0]
    occupied_by_robot = np.zeros((s, s), np.bool_)
    for i in range(n):
        occupied_by_robot[robots[i, 0], robots[i, 1]] = True
    er0 = 1 if corner < 2 else s - 1 - excl_side
    ec0 = 1 if corner % 2 == 0 else s - 1 - excl_side
    excluded = zone | occupied_by_robot
    excluded[er0 : er0 + excl_side, ec0 : ec0 + excl_side] = True
    base = grid.copy()
    obstacle_ok = (base == FREE) & ~zone & ~occupied_by_robot
    cells = np.empty(s * s, np.int64)
    for _ in range(_MAX_OBSTACLE_TRIES):
        _draw_obstacles(base, obstacle_ok, n_obs, u, p, grid, cells)
        if p[0] > u.shape[0]:
            return OUT_OF_UNIFORMS
        passable = grid == FREE
        reach = reachable_from(passable, robots[0, 0], robots[0, 1])
        team_ok = True
        for i in range(n):
            team_ok &= reach[robots[i, 0], robots[i, 1]]
        if not team_ok:
            continue  # the obstacles cut the team apart: redraw them
        code = _draw_target(passable & ~excluded, passable, reach, robots, u, p, grid, cells, info)
        if code != NO_TARGET:
            return code
        if p[0] > u.shape[0]:
            return OUT_OF_UNIFORMS
    return NO_TARGET
