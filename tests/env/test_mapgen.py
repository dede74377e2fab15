"""Map generator properties over many seeds (docs/design.md#maps-and-episodes)."""

import numpy as np
import pytest

from catmip_env import PRESETS, BatchedWorld, make_config
from catmip_env.config import SPAWN_BOX, TARGET_EXCLUSION_BOX
from catmip_env.constants import CLUE, FREE, OBSTACLE, TARGET, WALL
from catmip_env.kernels.mapgen import generate, room_bounds, target_exclusion_side

from .helpers import bfs_distance

N_MAPS = 150


def _maps(preset: str, n: int = N_MAPS, seed: int = 7, **overrides):
    cfg = make_config(preset, **overrides)
    eng = BatchedWorld(cfg, num_worlds=1, seed=seed)
    for k in range(n):
        rng, _ = eng.episode_streams(k)
        yield cfg, generate(cfg, rng)


def _corner_box(s, corner, side):
    rows = range(1, 1 + side) if corner in (0, 1) else range(s - 1 - side, s - 1)
    cols = range(1, 1 + side) if corner in (0, 2) else range(s - 1 - side, s - 1)
    return rows, cols


@pytest.mark.parametrize("preset", ["task1", "task2", "task3", "train"])
def test_generated_maps_satisfy_the_spec(preset):
    for cfg, ep in _maps(preset):
        g, s = ep.grid, cfg.map_size
        assert g.shape == (s, s)
        # outer ring of walls
        assert (g[0] == WALL).all() and (g[-1] == WALL).all()
        assert (g[:, 0] == WALL).all() and (g[:, -1] == WALL).all()
        # obstacle count
        assert (g == OBSTACLE).sum() == cfg.obstacles
        # exactly one target; clues are exactly its free 8-neighbours
        assert (g == TARGET).sum() == 1
        tr, tc = ep.target
        assert g[tr, tc] == TARGET
        nb = g[tr - 1 : tr + 2, tc - 1 : tc + 2].copy()
        nb[1, 1] = WALL  # the target itself
        assert (g == CLUE).sum() == (nb == CLUE).sum()
        assert not (nb == FREE).any(), "a free cell next to the target is not a clue"
        # spawn corner: every robot on a distinct walkable cell of the 4x4 box at the corner
        rows, cols = _corner_box(s, ep.corner, SPAWN_BOX)
        cells = {tuple(p) for p in ep.robots.tolist()}
        assert len(cells) == cfg.num_robots
        for r, c in cells:
            assert r in rows and c in cols and g[r, c] in (FREE, CLUE)
        # the target is outside the 8x8 box at the robots' corner and not on a doorway zone
        rows8, cols8 = _corner_box(s, ep.corner, target_exclusion_side(s))
        assert not (tr in rows8 and tc in cols8)
        for dr, dc in ep.doors:
            assert abs(dr - tr) + abs(dc - tc) > 1
            assert g[dr, dc] in (FREE, CLUE)
        # reachable: every robot reaches a cell orthogonally adjacent to the target
        passable = (g == FREE) | (g == CLUE)
        for r, c in ep.robots:
            dist = bfs_distance(passable, (int(r), int(c)))
            assert max(dist[tr + dr, tc + dc] for dr, dc in ((0, 1), (1, 0), (0, -1), (-1, 0))) >= 0
        # classes resolved from the team (random slots drawn from the allowed classes)
        for slot, k in zip(cfg.team, ep.classes):
            name = cfg.classes[k].name
            assert name == slot or (slot == "random" and name in cfg.random_classes)


def test_room_bounds():
    assert room_bounds(20, 4) == [0, 5, 10, 15, 19]
    assert room_bounds(32, 6) == [0, 5, 10, 15, 20, 25, 31]  # the last room takes the remainder
    assert room_bounds(15, 1) == [0, 14]


def test_walls_only_on_room_lattice_lines():
    """Every wall cell lies on the outer ring or on an inner lattice line of some room count
    w in [S//8, S//5]; doorways break every drawn segment."""
    for cfg, ep in _maps("task2", n=60):
        s = cfg.map_size
        lines = set()
        for w in range(max(1, s // 8), max(1, s // 5) + 1):
            lines |= set(room_bounds(s, w))
        rows, cols = np.nonzero(ep.grid == WALL)
        for r, c in zip(rows, cols):
            assert r in lines or c in lines


def test_obstacles_avoid_doorway_zones():
    for _, ep in _maps("task2", n=100):
        for dr, dc in ep.doors:
            for r, c in ((dr, dc), (dr + 1, dc), (dr - 1, dc), (dr, dc + 1), (dr, dc - 1)):
                assert ep.grid[r, c] != OBSTACLE


def test_map_stream_depends_only_on_seed_and_episode():
    cfg = PRESETS["task2"]
    a = BatchedWorld(cfg, 1, seed=3)
    b = BatchedWorld(cfg, 5, seed=3)
    ep_a = generate(cfg, a.episode_streams(4)[0])
    ep_b = generate(cfg, b.episode_streams(4)[0])
    assert np.array_equal(ep_a.grid, ep_b.grid) and np.array_equal(ep_a.robots, ep_b.robots)
    other = generate(cfg, a.episode_streams(5)[0])
    assert not np.array_equal(ep_a.grid, other.grid)
    c = BatchedWorld(cfg, 1, seed=4)
    assert not np.array_equal(ep_a.grid, generate(cfg, c.episode_streams(4)[0]).grid)


def test_random_team_slot_draws_both_classes():
    names = set()
    for cfg, ep in _maps("train", n=40):
        names.add(cfg.classes[ep.classes[2]].name)
    assert names == {"rescuer", "explorer"}


def test_exclusion_box_is_eight_on_paper_maps():
    assert [target_exclusion_side(s) for s in (15, 20, 32)] == [TARGET_EXCLUSION_BOX] * 3


@pytest.mark.parametrize("s", [10, 11, 13, 64])
def test_any_map_size_from_ten_works(s):
    for _, ep in _maps("task1", n=20, map_size=s):
        assert ep.grid.shape == (s, s) and (ep.grid == TARGET).sum() == 1
