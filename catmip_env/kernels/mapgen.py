"""Map generation: rooms with doorways, spawn corner, obstacles, a reachable target, clues.

The rules: docs/design.md#maps-and-episodes.

``generate(cfg, rng)`` draws everything of one episode from the episode's own map stream (a
``numpy.random.Generator`` seeded by ``(seed, episode_index)``), so every method evaluated with the same
seed sees exactly the same maps, teams and spawn poses. The Generator supplies one block of uniforms
per attempt; a numba kernel consumes them (a map costs tens of microseconds, not milliseconds).

Rules: room counts per axis ``w, h ~ U{max(1, S//8) .. max(1, S//5)}``; inner wall lines every
``S // w`` cells (the last room takes the remainder); each wall segment between adjacent rooms exists
with probability ``wall_prob`` and has one doorway at a uniform position; lattice junctions are walls
when a segment meets them. Robots take distinct free cells of the 4x4 box inside a uniform corner, with
uniform headings. Obstacles avoid doorway zones (doorways and their 4-neighbours) and robots. The
target avoids doorway zones and the 8x8 box at the robots' corner, and every robot must reach a cell
next to it (obstacles are redrawn if they cut the team off). Free cells around the target are clues.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from catmip_env.config import SPAWN_BOX, TARGET_EXCLUSION_BOX, EnvConfig
from catmip_env.constants import CLUE, FREE, OBSTACLE, STEPS, TARGET, WALL

__all__ = ["Episode", "generate", "room_bounds", "reachable_from", "target_exclusion_side"]

_MAX_OBSTACLE_TRIES = 100
_MAX_TARGET_TRIES = 50
_OUT_OF_UNIFORMS = -1
_NO_SPAWN_ROOM = -2
_NO_TARGET = -3


@dataclass
class Episode:
    """Everything drawn for one episode."""

    grid: np.ndarray  # (S, S) uint8 cell codes
    robots: np.ndarray  # (N, 2) int64 robot cells
    headings: np.ndarray  # (N,) int64
    classes: np.ndarray  # (N,) int64 class indices (random team slots resolved)
    target: tuple[int, int]
    corner: int  # 0 top-left, 1 top-right, 2 bottom-left, 3 bottom-right
    doors: np.ndarray  # (K, 2) doorway cells


def room_bounds(size: int, rooms: int) -> list[int]:
    """Wall lines along one axis: outer walls 0 and size-1, inner walls every ``size // rooms``."""
    step = size // rooms
    return [0] + [k * step for k in range(1, rooms)] + [size - 1]


def target_exclusion_side(s: int) -> int:
    """Side of the box at the spawn corner that the target avoids: 8, shrunk on maps below 12x12
    so that some interior remains outside it."""
    return min(TARGET_EXCLUSION_BOX, s - 4)


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


@njit(cache=True, inline="always")
def _take(u: np.ndarray, p: np.ndarray) -> float:
    """Next uniform of the block (0.5 once exhausted; the caller then retries with a new block)."""
    k = p[0]
    p[0] = k + 1
    return u[k] if k < u.shape[0] else 0.5


@njit(cache=True, inline="always")
def _below(u: np.ndarray, p: np.ndarray, n: int) -> int:
    """Uniform int in [0, n)."""
    return min(int(_take(u, p) * n), n - 1)


@njit(cache=True)
def _bounds(s: int, rooms: int) -> np.ndarray:
    out = np.empty(rooms + 1, np.int64)
    step = s // rooms
    for k in range(rooms):
        out[k] = k * step
    out[rooms] = s - 1
    return out


@njit(cache=True)
def _choose(cells: np.ndarray, count: int, k: int, u: np.ndarray, p: np.ndarray) -> None:
    """Move a uniform k-subset of cells[:count] to the front (partial Fisher-Yates)."""
    for j in range(k):
        m = j + _below(u, p, count - j)
        cells[j], cells[m] = cells[m], cells[j]


@njit(cache=True)
def _draw_walls(
    s: int, wall_prob: float, u: np.ndarray, p: np.ndarray, grid: np.ndarray, doors: np.ndarray
) -> int:
    """Outer walls, then the room lattice: each segment between adjacent rooms with probability
    ``wall_prob``, with one doorway; junctions that a segment meets are walls. Returns the number of
    doorways written to ``doors``."""
    grid[:, :] = FREE
    grid[0, :] = WALL
    grid[s - 1, :] = WALL
    grid[:, 0] = WALL
    grid[:, s - 1] = WALL
    lo = max(1, s // 8)
    hi = max(lo, s // 5)
    n_cols = lo + _below(u, p, hi - lo + 1)
    n_rows = lo + _below(u, p, hi - lo + 1)
    cb, rb = _bounds(s, n_cols), _bounds(s, n_rows)
    junction = np.zeros((n_rows + 1, n_cols + 1), np.bool_)
    nd = 0
    for i in range(n_rows):  # vertical segments between horizontally adjacent rooms
        for j in range(1, n_cols):
            if _take(u, p) < wall_prob:
                r_lo, r_hi = rb[i] + 1, rb[i + 1]
                grid[r_lo:r_hi, cb[j]] = WALL
                door = r_lo + _below(u, p, r_hi - r_lo)
                grid[door, cb[j]] = FREE
                doors[nd, 0], doors[nd, 1] = door, cb[j]
                nd += 1
                junction[i, j] = True
                junction[i + 1, j] = True
    for i in range(1, n_rows):  # horizontal segments between vertically adjacent rooms
        for j in range(n_cols):
            if _take(u, p) < wall_prob:
                c_lo, c_hi = cb[j] + 1, cb[j + 1]
                grid[rb[i], c_lo:c_hi] = WALL
                door = c_lo + _below(u, p, c_hi - c_lo)
                grid[rb[i], door] = FREE
                doors[nd, 0], doors[nd, 1] = rb[i], door
                nd += 1
                junction[i, j] = True
                junction[i, j + 1] = True
    for i in range(n_rows + 1):
        for j in range(n_cols + 1):
            if junction[i, j]:
                grid[rb[i], cb[j]] = WALL
    return nd


@njit(cache=True)
def _doorway_zone(s: int, doors: np.ndarray, nd: int) -> np.ndarray:
    """(s, s) bool: the doorways and their 4-neighbours (kept free of obstacles and the target)."""
    zone = np.zeros((s, s), np.bool_)
    for k in range(nd):
        r, c = doors[k, 0], doors[k, 1]
        zone[r, c] = True
        zone[r + 1, c] = True
        zone[r - 1, c] = True
        zone[r, c + 1] = True
        zone[r, c - 1] = True
    return zone


@njit(cache=True)
def _place_robots(
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
        return _OUT_OF_UNIFORMS
    if count < n:
        return _NO_SPAWN_ROOM
    _choose(cells, count, n, u, p)
    for i in range(n):
        robots[i, 0], robots[i, 1] = cells[i] // s, cells[i] % s
    for i in range(n):
        headings[i] = _below(u, p, 4)
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
    _choose(cells, count, k, u, p)
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
    off; writes it (and its clues) to ``grid`` and ``info[1:3]``. 0, or _NO_TARGET / _OUT_OF_UNIFORMS."""
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
        m = _below(u, p, count)
        tr, tc = cells[m] // s, cells[m] % s
        passable[tr, tc] = False  # the target is impassable: it must not cut anyone off
        reach2 = reachable_from(passable, robots[0, 0], robots[0, 1])
        passable[tr, tc] = True
        ok = reach2[tr - 1, tc] or reach2[tr + 1, tc] or reach2[tr, tc - 1] or reach2[tr, tc + 1]
        for i in range(n):
            ok &= reach2[robots[i, 0], robots[i, 1]]
        if ok:
            if p[0] > u.shape[0]:
                return _OUT_OF_UNIFORMS
            grid[tr, tc] = TARGET
            for dr in range(-1, 2):
                for dc in range(-1, 2):
                    if grid[tr + dr, tc + dc] == FREE:
                        grid[tr + dr, tc + dc] = CLUE
            info[1], info[2] = tr, tc
            return 0
        count -= 1
        cells[m] = cells[count]
    return _NO_TARGET


@njit(cache=True)
def _place_obstacles_and_target(
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
            return _OUT_OF_UNIFORMS
        passable = grid == FREE
        reach = reachable_from(passable, robots[0, 0], robots[0, 1])
        team_ok = True
        for i in range(n):
            team_ok &= reach[robots[i, 0], robots[i, 1]]
        if not team_ok:
            continue  # the obstacles cut the team apart: redraw them
        code = _draw_target(passable & ~excluded, passable, reach, robots, u, p, grid, cells, info)
        if code != _NO_TARGET:
            return code
        if p[0] > u.shape[0]:
            return _OUT_OF_UNIFORMS
    return _NO_TARGET


@njit(cache=True)
def _generate(
    s: int,
    n: int,
    n_obs: int,
    wall_prob: float,
    excl_side: int,
    u: np.ndarray,  # block of uniforms in [0, 1)
    grid: np.ndarray,  # (s, s) uint8 out
    robots: np.ndarray,  # (n, 2) int64 out
    headings: np.ndarray,  # (n,) int64 out
    doors: np.ndarray,  # (max_doors, 2) int64 out
    info: np.ndarray,  # (4,) int64 out: corner, target row, target col, number of doors
) -> int:
    """Draw one map; returns 0, or a negative code (_OUT_OF_UNIFORMS, _NO_SPAWN_ROOM, _NO_TARGET).

    The uniforms of ``u`` are consumed in a fixed order: room counts, wall segments and doorways,
    the spawn corner, the robots' cells and headings, then obstacles and target per attempt.
    """
    p = np.zeros(1, np.int64)  # index of the next uniform
    nd = _draw_walls(s, wall_prob, u, p, grid, doors)
    zone = _doorway_zone(s, doors, nd)
    info[3] = nd
    corner = _below(u, p, 4)
    info[0] = corner
    code = _place_robots(s, n, corner, u, p, grid, robots, headings)
    if code != 0:
        return code
    return _place_obstacles_and_target(n_obs, excl_side, corner, zone, u, p, grid, robots, info)


def generate(cfg: EnvConfig, rng: np.random.Generator) -> Episode:
    """Draw one episode's map, team and spawn poses from ``rng`` (see module docstring)."""
    s, n = cfg.map_size, cfg.num_robots
    classes = np.empty(n, dtype=np.int64)
    for i, slot in enumerate(cfg.team):
        if slot == "random":
            slot = cfg.random_classes[int(rng.integers(len(cfg.random_classes)))]
        classes[i] = cfg.class_index(slot)
    grid = np.empty((s, s), np.uint8)
    robots = np.empty((n, 2), np.int64)
    headings = np.empty(n, np.int64)
    doors = np.empty((2 * (s // 5 + 1) ** 2, 2), np.int64)
    info = np.zeros(4, np.int64)
    block = 4 * (s // 5 + 1) ** 2 + 4 * n + 2 * cfg.obstacles + 64
    while True:
        code = _generate(
            s, n, cfg.obstacles, cfg.wall_prob, target_exclusion_side(s), rng.random(block),
            grid, robots, headings, doors, info,
        )  # fmt: skip
        if code != _OUT_OF_UNIFORMS:
            break
        block *= 4  # rare: many redraws; continue the same stream with a bigger block
    if code == _NO_SPAWN_ROOM:
        raise ValueError(f"the spawn box of a {s}x{s} map has fewer free cells than {n} robots")
    if code == _NO_TARGET:  # pragma: no cover - needs an adversarial config
        raise RuntimeError("map generation found no reachable target; lower num_obstacles")
    return Episode(
        grid=grid,
        robots=robots,
        headings=headings,
        classes=classes,
        target=(int(info[1]), int(info[2])),
        corner=int(info[0]),
        doors=doors[: info[3]].copy(),
    )
