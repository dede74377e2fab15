"""Shared test helpers: engines on hand-drawn ASCII maps and rollouts with random actions."""

from __future__ import annotations

import numpy as np

from catmip_env import BatchedEngine, EnvConfig, make_config

# A non-square map: two rooms joined by a doorway, a few obstacles, the target in the right room.
TWO_ROOMS = """
#############
#01.....#...#
#.......#...#
#...o.......#
#.......#.T.#
#.......#...#
#############
"""


def layout_config(layout: str, team=("rescuer", "explorer"), **overrides) -> EnvConfig:
    return EnvConfig(layout=layout, team=tuple(team), horizon_ticks=200).replace(**overrides)


def layout_engine(layout: str, team=("rescuer", "explorer"), seed=0, **overrides) -> BatchedEngine:
    eng = BatchedEngine(layout_config(layout, team, **overrides), num_worlds=1, seed=seed)
    eng.reset()
    return eng


def preset_engine(preset: str, num_worlds: int = 4, seed: int = 0, **overrides) -> BatchedEngine:
    eng = BatchedEngine(make_config(preset, **overrides), num_worlds=num_worlds, seed=seed)
    eng.reset()
    return eng


def random_actions(rng: np.random.Generator, eng: BatchedEngine) -> np.ndarray:
    return rng.integers(0, 4, size=(eng.num_worlds, eng.num_robots))


def bfs_distance(passable: np.ndarray, start: tuple[int, int]) -> np.ndarray:
    """Plain-Python BFS distance field (-1 = unreachable), the reference for engine checks."""
    h, w = passable.shape
    dist = np.full((h, w), -1, np.int64)
    dist[start] = 0
    frontier = [start]
    while frontier:
        nxt = []
        for r, c in frontier:
            for dr, dc in ((0, 1), (1, 0), (0, -1), (-1, 0)):
                rr, cc = r + dr, c + dc
                if 0 <= rr < h and 0 <= cc < w and passable[rr, cc] and dist[rr, cc] < 0:
                    dist[rr, cc] = dist[r, c] + 1
                    nxt.append((rr, cc))
        frontier = nxt
    return dist
