"""Map generation (SPEC §1.1): rooms with doorways, spawn corner, obstacles, a reachable target, clues.

``generate(cfg, rng)`` draws everything of one episode from the episode's own map stream (a
``numpy.random.Generator`` seeded by ``(seed, episode_index)``), so every method evaluated with the same
seed sees exactly the same maps, teams and spawn poses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from catmip_env.config import SPAWN_BOX, TARGET_EXCLUSION_BOX, EnvConfig
from catmip_env.types import CLUE, FREE, OBSTACLE, TARGET, WALL

__all__ = ["Episode", "generate", "room_bounds", "reachable_from", "target_exclusion_side"]

_MAX_OBSTACLE_TRIES = 100
_MAX_TARGET_TRIES = 50


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
        for dr, dc in ((0, 1), (1, 0), (0, -1), (-1, 0)):
            rr, cc = r + dr, c + dc
            if 0 <= rr < h and 0 <= cc < w and passable[rr, cc] and not seen[rr, cc]:
                seen[rr, cc] = True
                queue[tail] = rr * w + cc
                tail += 1
    return seen


def _rooms(s: int, wall_prob: float, rng: np.random.Generator) -> tuple[np.ndarray, list[tuple[int, int]]]:
    grid = np.zeros((s, s), dtype=np.uint8)
    grid[0, :] = grid[-1, :] = grid[:, 0] = grid[:, -1] = WALL
    lo = max(1, s // 8)
    hi = max(lo, s // 5)
    n_cols, n_rows = (int(x) for x in rng.integers(lo, hi + 1, size=2))
    cb, rb = room_bounds(s, n_cols), room_bounds(s, n_rows)
    doors: list[tuple[int, int]] = []
    junction_wall = np.zeros((len(rb), len(cb)), dtype=bool)
    # Vertical segments between horizontally adjacent rooms (room row i, wall column cb[j]).
    for i in range(n_rows):
        for j in range(1, n_cols):
            if rng.random() < wall_prob:
                r_lo, r_hi = rb[i] + 1, rb[i + 1]  # interior rows of the segment
                grid[r_lo:r_hi, cb[j]] = WALL
                door = int(rng.integers(r_lo, r_hi))
                grid[door, cb[j]] = FREE
                doors.append((door, cb[j]))
                junction_wall[i, j] = junction_wall[i + 1, j] = True
    # Horizontal segments between vertically adjacent rooms (wall row rb[i], room column j).
    for i in range(1, n_rows):
        for j in range(n_cols):
            if rng.random() < wall_prob:
                c_lo, c_hi = cb[j] + 1, cb[j + 1]
                grid[rb[i], c_lo:c_hi] = WALL
                door = int(rng.integers(c_lo, c_hi))
                grid[rb[i], door] = FREE
                doors.append((rb[i], door))
                junction_wall[i, j] = junction_wall[i, j + 1] = True
    for i, r in enumerate(rb):
        for j, c in enumerate(cb):
            if junction_wall[i, j]:
                grid[r, c] = WALL
    return grid, doors


def target_exclusion_side(s: int) -> int:
    """Side of the box at the spawn corner that the target avoids: 8, shrunk on maps below 12x12
    so that some interior remains outside it."""
    return min(TARGET_EXCLUSION_BOX, s - 4)


def _box(s: int, corner: int, side: int) -> tuple[slice, slice]:
    """Rows/cols of the ``side`` x ``side`` box just inside a corner."""
    rows = slice(1, 1 + side) if corner in (0, 1) else slice(s - 1 - side, s - 1)
    cols = slice(1, 1 + side) if corner in (0, 2) else slice(s - 1 - side, s - 1)
    return rows, cols


def generate(cfg: EnvConfig, rng: np.random.Generator) -> Episode:
    """Draw one episode's map, team and spawn poses from ``rng`` (see module docstring)."""
    s, n = cfg.map_size, cfg.num_robots
    grid, doors = _rooms(s, cfg.wall_prob, rng)
    door_zone = np.zeros((s, s), dtype=bool)
    for r, c in doors:
        door_zone[r, c] = True
        for dr, dc in ((0, 1), (1, 0), (0, -1), (-1, 0)):
            door_zone[r + dr, c + dc] = True

    # Robots: a uniformly drawn corner, distinct free cells of its 4x4 box, random headings.
    corner = int(rng.integers(4))
    rows, cols = _box(s, corner, SPAWN_BOX)
    box = np.zeros((s, s), dtype=bool)
    box[rows, cols] = True
    spawn_cells = np.flatnonzero(box & (grid == FREE))
    picks = rng.choice(spawn_cells, size=n, replace=False)
    robots = np.stack([picks // s, picks % s], axis=1).astype(np.int64)
    headings = rng.integers(4, size=n).astype(np.int64)
    classes = np.empty(n, dtype=np.int64)
    for i, slot in enumerate(cfg.team):
        name = slot if slot != "random" else cfg.random_classes[int(rng.integers(len(cfg.random_classes)))]
        classes[i] = cfg.class_index(name)

    robot_mask = np.zeros((s, s), dtype=bool)
    robot_mask[robots[:, 0], robots[:, 1]] = True
    excl = np.zeros((s, s), dtype=bool)
    excl[_box(s, corner, target_exclusion_side(s))] = True
    obstacle_cells = np.flatnonzero((grid == FREE) & ~door_zone & ~robot_mask)
    n_obs = min(cfg.obstacles, len(obstacle_cells))
    for _ in range(_MAX_OBSTACLE_TRIES):
        world = grid.copy()
        world.flat[rng.choice(obstacle_cells, size=n_obs, replace=False)] = OBSTACLE
        target = _place_target(world, robots, door_zone | excl | robot_mask, rng)
        if target is not None:
            break
    else:  # pragma: no cover - needs an adversarial config
        raise RuntimeError("map generation found no reachable target; lower num_obstacles")
    tr, tc = target
    world[tr, tc] = TARGET
    nb = world[tr - 1 : tr + 2, tc - 1 : tc + 2]
    nb[nb == FREE] = CLUE
    return Episode(
        grid=world,
        robots=robots,
        headings=headings,
        classes=classes,
        target=(tr, tc),
        corner=corner,
        doors=np.array(doors, dtype=np.int64).reshape(-1, 2),
    )


def _place_target(
    world: np.ndarray, robots: np.ndarray, forbidden: np.ndarray, rng: np.random.Generator
) -> tuple[int, int] | None:
    """A target cell reachable by every robot (None if the obstacles cut the team off)."""
    s = world.shape[1]
    passable = world == FREE
    reach = reachable_from(passable, int(robots[0, 0]), int(robots[0, 1]))
    if not reach[robots[:, 0], robots[:, 1]].all():
        return None
    # Candidates: free, allowed, with a reachable 4-neighbour.
    nb_reach = np.zeros_like(reach)
    nb_reach[1:, :] |= reach[:-1, :]
    nb_reach[:-1, :] |= reach[1:, :]
    nb_reach[:, 1:] |= reach[:, :-1]
    nb_reach[:, :-1] |= reach[:, 1:]
    candidates = np.flatnonzero(passable & ~forbidden & nb_reach)
    for _ in range(_MAX_TARGET_TRIES):
        if len(candidates) == 0:
            return None
        k = int(rng.integers(len(candidates)))
        tr, tc = divmod(int(candidates[k]), s)
        # The target is impassable: check it does not cut robots off from each other or itself.
        passable[tr, tc] = False
        reach2 = reachable_from(passable, int(robots[0, 0]), int(robots[0, 1]))
        passable[tr, tc] = True
        if reach2[robots[:, 0], robots[:, 1]].all() and (
            reach2[tr - 1, tc] or reach2[tr + 1, tc] or reach2[tr, tc - 1] or reach2[tr, tc + 1]
        ):
            return tr, tc
        candidates = np.delete(candidates, k)
    return None
