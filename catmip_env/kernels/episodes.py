"""New episodes loaded into worlds in one ``nogil`` kernel (a reset, on every thread).

:func:`load_episodes` does for each world what the Python streams do
(:meth:`~catmip_env.engines.world.BatchedWorld.episode_streams`, :func:`~.mapgen.generate`,
:func:`~catmip_env.engines.world.world_key`), drawing from the same numpy streams bit for bit
(:mod:`~.seeding`): the random team slots, the map (or the config's fixed layout), the communication
range, the dynamics state and the world key. It costs about 19 us a world where the Python streams
cost about 108 us under the GIL.
"""

from __future__ import annotations

import numpy as np
from numba import njit, uint64

from catmip_env.kernels.mapgen import draw_map
from catmip_env.kernels.placement import OUT_OF_UNIFORMS
from catmip_env.kernels.seeding import pcg64_integer, pcg64_stream, pcg64_uniforms, seed_words
from catmip_env.kernels.state import KernelState

__all__ = ["load_episodes"]


@njit(cache=True, nogil=True)
def load_episodes(
    worlds: np.ndarray,  # (K,) int64 the worlds to load
    episodes: np.ndarray,  # (K,) int64 their episode indices
    lo: int,  # only the worlds in [lo, hi) are loaded (one thread's chunk)
    hi: int,
    seed: np.ndarray,  # the base seed's 32-bit words (seeding.int_words)
    s: KernelState,
    world_keys: np.ndarray,  # (B,) int64 out
    codes: np.ndarray,  # (K,) int64 out: 0, or the map generator's error code
    team: np.ndarray,  # (N,) int64 each slot's class index, -1 for a random slot
    random_classes: np.ndarray,  # (R,) int64 the class indices a random slot draws from
    speed_of: np.ndarray,  # (C,) int64 ticks per action of each class
    rescue_of: np.ndarray,  # (C,) bool
    comm_of: np.ndarray,  # (M,) float64 the communication ranges an episode draws from
    size: int,
    obstacles: int,
    wall_prob: float,
    excl_side: int,  # mapgen.target_exclusion_side(size)
    block: int,  # the first block of uniforms (generate's)
    layout_grid: np.ndarray,  # (H, W) uint8 the fixed layout's map, or (0, 0): generated maps
    layout_robots: np.ndarray,  # (N, 2) int64 the layout's robot cells (unused for generated maps)
    layout_headings: np.ndarray,  # (N,) int64
    layout_target: np.ndarray,  # (2,) int64
) -> None:
    """Load episode ``episodes[j]`` of ``seed`` into world ``worlds[j]`` for the worlds of the chunk; a
    world whose map cannot be drawn is left as it was, sets ``codes[j]`` and ends the call (the caller
    raises)."""
    n = team.shape[0]
    classes = np.empty(n, np.int64)
    doors = np.empty((2 * (size // 5 + 1) ** 2, 2), np.int64)
    info = np.zeros(4, np.int64)
    grid = np.empty((size, size), np.uint8)  # a map is drawn here, then copied into its world
    robots, headings = np.empty((n, 2), np.int64), np.empty(n, np.int64)
    for j in range(worlds.shape[0]):
        b, ep = worlds[j], episodes[j]
        if b < lo or b >= hi:
            continue
        g = pcg64_stream(seed, ep, 0)  # the map stream
        for i in range(n):
            pick = team[i]
            if pick < 0:
                pick = random_classes[pcg64_integer(g, random_classes.shape[0])]
            classes[i] = pick
        if layout_grid.shape[0] > 0:
            s.grid[b] = layout_grid
            s.pos[b] = layout_robots
            s.heading[b] = layout_headings
            s.target[b] = layout_target
        else:
            code = _draw(g, block, size, n, obstacles, wall_prob, excl_side, grid, robots, headings, doors,
                         info)  # fmt: skip
            codes[j] = code
            if code != 0:  # the world is left as it was
                return
            s.grid[b] = grid
            s.pos[b] = robots
            s.heading[b] = headings
            s.target[b, 0], s.target[b, 1] = info[1], info[2]
        for i in range(n):
            s.cls[b, i] = classes[i]
            s.speed[b, i] = speed_of[classes[i]]
            s.can_rescue[b, i] = rescue_of[classes[i]]
        s.belief[b] = 0
        s.comp[b] = 0
        s.goal[b] = -1
        s.rng[b] = seed_words(seed, ep, 1, 1)[0]  # the dynamics stream
        s.ticks[b] = 0
        s.moves[b] = 0
        s.collisions[b] = 0
        s.found_tick[b] = -1
        s.informed_tick[b] = -1
        s.rescue_tick[b] = -1
        s.heard_tick[b] = -1
        s.done[b] = False
        s.episode[b] = ep
        world_keys[b] = np.int64(seed_words(seed, ep, 2, 1)[0] >> uint64(1))
        s.comm_sigma[b] = comm_of[pcg64_integer(g, comm_of.shape[0])]  # after the map: no map depends on it


@njit(cache=True, nogil=True)
def _draw(g, block, size, n, obstacles, wall_prob, excl_side, grid, robots, headings, doors, info) -> int:
    """:func:`~.mapgen.draw_map` from the stream ``g``: a block of ``block`` uniforms, 4x as many at each
    retry (rare: many redraws), the same stream going on; 0 or the generator's error code."""
    need = block
    while True:
        code = draw_map(size, n, obstacles, wall_prob, excl_side, pcg64_uniforms(g, need), grid, robots,
                        headings, doors, info)  # fmt: skip
        if code != OUT_OF_UNIFORMS:
            return code
        need *= 4
