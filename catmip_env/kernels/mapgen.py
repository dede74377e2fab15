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

The rooms are drawn here; the robots, obstacles, target and clues in :mod:`~catmip_env.kernels.placement`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from catmip_env.config import TARGET_EXCLUSION_BOX, EnvConfig
from catmip_env.constants import FREE, WALL
from catmip_env.kernels.placement import (
    NO_SPAWN_ROOM,
    NO_TARGET,
    OUT_OF_UNIFORMS,
    place_obstacles_and_target,
    place_robots,
)
from catmip_env.kernels.rng import block_randint, block_uniform

__all__ = [
    "Episode",
    "draw_map",
    "first_block",
    "generate",
    "raise_map_error",
    "room_bounds",
    "target_exclusion_side",
]


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
def _bounds(s: int, rooms: int) -> np.ndarray:
    out = np.empty(rooms + 1, np.int64)
    step = s // rooms
    for k in range(rooms):
        out[k] = k * step
    out[rooms] = s - 1
    return out


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
    n_cols = lo + block_randint(u, p, hi - lo + 1)
    n_rows = lo + block_randint(u, p, hi - lo + 1)
    cb, rb = _bounds(s, n_cols), _bounds(s, n_rows)
    junction = np.zeros((n_rows + 1, n_cols + 1), np.bool_)
    nd = 0
    for i in range(n_rows):  # vertical segments between horizontally adjacent rooms
        for j in range(1, n_cols):
            if block_uniform(u, p) < wall_prob:
                r_lo, r_hi = rb[i] + 1, rb[i + 1]
                grid[r_lo:r_hi, cb[j]] = WALL
                door = r_lo + block_randint(u, p, r_hi - r_lo)
                grid[door, cb[j]] = FREE
                doors[nd, 0], doors[nd, 1] = door, cb[j]
                nd += 1
                junction[i, j] = True
                junction[i + 1, j] = True
    for i in range(1, n_rows):  # horizontal segments between vertically adjacent rooms
        for j in range(n_cols):
            if block_uniform(u, p) < wall_prob:
                c_lo, c_hi = cb[j] + 1, cb[j + 1]
                grid[rb[i], c_lo:c_hi] = WALL
                door = c_lo + block_randint(u, p, c_hi - c_lo)
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
def draw_map(
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
    """Draw one map; returns 0, or a negative code (OUT_OF_UNIFORMS, NO_SPAWN_ROOM, NO_TARGET).

    The uniforms of ``u`` are consumed in a fixed order: room counts, wall segments and doorways,
    the spawn corner, the robots' cells and headings, then obstacles and target per attempt.
    """
    p = np.zeros(1, np.int64)  # index of the next uniform
    nd = _draw_walls(s, wall_prob, u, p, grid, doors)
    zone = _doorway_zone(s, doors, nd)
    info[3] = nd
    corner = block_randint(u, p, 4)
    info[0] = corner
    code = place_robots(s, n, corner, u, p, grid, robots, headings)
    if code != 0:
        return code
    return place_obstacles_and_target(n_obs, excl_side, corner, zone, u, p, grid, robots, info)


def first_block(cfg: EnvConfig) -> int:
    """How many uniforms a map's first attempt draws (4x as many at each retry)."""
    return 4 * (cfg.map_size // 5 + 1) ** 2 + 4 * cfg.num_robots + 2 * cfg.obstacles + 64


def raise_map_error(cfg: EnvConfig, code: int) -> None:
    """The error of a map that :func:`draw_map` could not draw (code != 0); nothing for 0."""
    if code == NO_SPAWN_ROOM:
        s, n = cfg.map_size, cfg.num_robots
        raise ValueError(f"the spawn box of a {s}x{s} map has fewer free cells than {n} robots")
    if code == NO_TARGET:  # pragma: no cover - needs an adversarial config
        raise RuntimeError("map generation found no reachable target; lower num_obstacles")


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
    block = first_block(cfg)
    while True:
        code = draw_map(
            s,
            n,
            cfg.obstacles,
            cfg.wall_prob,
            target_exclusion_side(s),
            rng.random(block),
            grid,
            robots,
            headings,
            doors,
            info,
        )
        if code != OUT_OF_UNIFORMS:
            break
        block *= 4  # rare: many redraws; continue the same stream with a bigger block
    raise_map_error(cfg, code)
    return Episode(
        grid=grid,
        robots=robots,
        headings=headings,
        classes=classes,
        target=(int(info[1]), int(info[2])),
        corner=int(info[0]),
        doors=doors[: info[3]].copy(),
    )
