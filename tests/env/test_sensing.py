"""Line-of-sight sensing: property tests against an independent geometric check, plus hand maps."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from catmip_env.constants import EXPLORED, OBSTACLE, WALL
from catmip_env.kernels.sensing import (
    RAY_CELLS,
    RAY_NBLOCK,
    VIEW_BLOCKERS,
    VIEW_OFFSETS,
    sense_robot,
    to_world,
)

from .helpers import layout_engine

H = W = 13


def _sense(grid, r, c, heading):
    belief = np.zeros((1, 1) + grid.shape, np.uint8)
    sense_robot(grid[None], belief, 0, 0, r, c, heading, VIEW_OFFSETS, VIEW_BLOCKERS, RAY_NBLOCK)
    return (belief[0, 0] & EXPLORED) != 0


def _cell_of(x, y):
    return int(np.floor(x + 0.5)), int(np.floor(y + 0.5))


def _clear_sight(opaque, r0, c0, r1, c1, eps=1e-9):
    """Independent check by dense sampling: the open segment between the two centres meets no
    opaque cell interior, and never squeezes through a corner between two opaque cells."""
    dr, dc = r1 - r0, c1 - c0
    length = np.hypot(dr, dc)
    nr, nc = -dc / length, dr / length  # unit normal of the segment
    # The grid of t holds every multiple of 1 / (2 |dr| |dc|), so lattice corners are sampled.
    samples = 2 * max(abs(dr), 1) * max(abs(dc), 1) * 60 + 1
    for t in np.linspace(0.0, 1.0, samples)[1:-1]:
        x, y = r0 + t * dr, c0 + t * dc
        fx, fy = x + 0.5 - np.floor(x + 0.5), y + 0.5 - np.floor(y + 0.5)
        on_x = min(fx, 1 - fx) < eps
        on_y = min(fy, 1 - fy) < eps
        if on_x and on_y:  # a lattice corner: both sides of the segment there
            a = _cell_of(x + 1e-3 * nr, y + 1e-3 * nc)
            b = _cell_of(x - 1e-3 * nr, y - 1e-3 * nc)
            if opaque[a] and opaque[b]:
                return False
            continue
        if on_x or on_y:
            continue
        cell = _cell_of(x, y)
        if cell in ((r0, c0), (r1, c1)):
            continue
        if opaque[cell]:
            return False
    return True


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    density=st.floats(0.0, 0.5),
    r=st.integers(1, H - 2),
    c=st.integers(1, W - 2),
    heading=st.integers(0, 3),
)
def test_visible_iff_clear_line_of_sight(seed, density, r, c, heading):
    rng = np.random.default_rng(seed)
    grid = np.where(rng.random((H, W)) < density, OBSTACLE, 0).astype(np.uint8)
    grid[0, :] = grid[-1, :] = grid[:, 0] = grid[:, -1] = WALL
    grid[r, c] = 0
    opaque = (grid == WALL) | (grid == OBSTACLE)
    seen = _sense(grid, r, c, heading)
    view = set()
    for f, l in RAY_CELLS:
        rr, cc = to_world(r, c, heading, f, l)
        if 0 <= rr < H and 0 <= cc < W:
            view.add((rr, cc))
            expect = (rr, cc) == (r, c) or _clear_sight(opaque, r, c, rr, cc)
            assert seen[rr, cc] == expect, (rr, cc)
    # nothing outside the view (in particular nothing behind the robot) is seen
    for rr, cc in zip(*np.nonzero(seen)):
        assert (rr, cc) in view


def test_view_is_own_row_and_six_rows_ahead():
    grid = np.zeros((H, W), np.uint8)
    grid[0, :] = grid[-1, :] = grid[:, 0] = grid[:, -1] = WALL
    seen = _sense(grid, 6, 3, 0)  # facing east in an empty room
    rows, cols = np.nonzero(seen)
    assert rows.min() == 3 and rows.max() == 9 and cols.min() == 3 and cols.max() == 9
    assert seen.sum() == 49
    seen_n = _sense(grid, 10, 6, 3)  # facing north
    rows, cols = np.nonzero(seen_n)
    assert rows.min() == 4 and rows.max() == 10 and cols.min() == 3 and cols.max() == 9


def test_walls_block_sight_on_a_hand_map():
    eng = layout_engine(
        """
        ##########
        #0...#...#
        #....#.T.#
        #1.......#
        ##########
        """
    )
    explored = (eng.state.belief[0, 0] & EXPLORED) != 0
    # robot_0 at (1,1) facing east sees the wall at column 5 but not past it in rows 1-2
    assert explored[1, 5] and explored[1, 4]
    assert not explored[1, 6] and not explored[2, 6]
    # through the open row 3 it sees further east
    assert explored[3, 7]
