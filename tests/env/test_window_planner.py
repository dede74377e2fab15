"""Planners projected into the goal window (catmip_env.planners.window): hand-drawn paths and whole
episodes against the cell-mode planners."""

import numpy as np
import pytest

from catmip_env import make_config
from catmip_env.constants import EXPLORED, OCCUPIED
from catmip_env.engines.events import EventEngine
from catmip_env.planners.baselines import make_planner
from catmip_env.planners.window import make_window_planner, project_goal

# '#' known occupied, '.' known free, '?' unexplored (counts as free), 'R' the robot, 'o' another robot
MAP = """
###############
#R....#.......#
#.....#.......#
#.....#.......#
#.....#.......#
#.............#
#?????#....o..#
###############
"""


def _belief(layout: str):
    rows = [r for r in layout.strip().splitlines()]
    grid = np.array([list(r) for r in rows])
    belief = np.where(grid == "?", 0, EXPLORED).astype(np.uint8)
    belief[grid == "#"] |= OCCUPIED
    me = np.argwhere(grid == "R")[0]
    others = np.argwhere(grid == "o")
    return belief, np.concatenate([me[None], others]).astype(np.int64)


def _project(belief, pos, goal, window=7, mask=None, heading=0):
    h, w = belief.shape
    mask = np.ones(window * window, np.int8) if mask is None else mask
    dist, queue = np.empty(h * w, np.int64), np.empty(h * w, np.int64)
    return project_goal(belief, pos, 0, heading, goal[0], goal[1], window, mask, dist, queue)


def _mask_out(*cells, pos=((1, 1),), window=7):
    mask = np.ones(window * window, np.int8)
    for r, c in cells:
        mask[(r - pos[0][0] + window // 2) * window + c - pos[0][1] + window // 2] = 0
    return mask


def _cell(action, pos, window=7):
    return (int(pos[0, 0] + action // window - window // 2), int(pos[0, 1] + action % window - window // 2))


def test_a_goal_inside_the_window_is_kept_and_the_own_cell_is_stay():
    belief, pos = _belief(MAP)
    assert _cell(_project(belief, pos, (3, 4)), pos) == (3, 4)
    assert _project(belief, pos, (1, 1)) == 24  # the centre of a 7 x 7 window


def test_a_far_goal_becomes_the_farthest_window_cell_of_the_controllers_path():
    belief, pos = _belief(MAP)
    # the goal is behind the wall at column 6: every shortest path (17 steps) goes through the gap at
    # (5, 6). The controller keeps its heading while that stays on a shortest path: heading east it runs
    # along row 1 and leaves the window (cols 1..4) after (1, 4); heading south it runs down column 1.
    goal = (1, 10)
    assert _cell(_project(belief, pos, goal, heading=0), pos) == (1, 4)
    assert _cell(_project(belief, pos, goal, heading=1), pos) == (4, 1)
    # heading west or north no first move is shorter that way: the order E, S, W, N picks east
    assert _cell(_project(belief, pos, goal, heading=2), pos) == (1, 4)
    # a masked path cell gives way to the farthest allowed one before it
    assert _cell(_project(belief, pos, goal, mask=_mask_out((1, 4)), heading=0), pos) == (1, 3)


def test_the_heading_free_path_starts_with_east_south_west_north_and_ignores_the_heading():
    belief, pos = _belief(MAP)
    # heading -1: no heading; east is the first of E, S, W, N on a shortest path to (1, 10), then straight
    # on along row 1 -- what heading east gives, where heading south gives column 1
    assert _cell(_project(belief, pos, (1, 10), heading=-1), pos) == (1, 4)
    assert _cell(_project(belief, pos, (1, 10), heading=1), pos) == (4, 1)
    # due south: east is not on a shortest path, south is
    assert _cell(_project(belief, pos, (6, 1), heading=-1), pos) == (4, 1)


@pytest.mark.parametrize("name", ["nearest", "rrt"])
def test_heading_free_window_planners_do_not_read_the_headings(name):
    eng = EventEngine(make_config("task2"), 6, 3)
    eng.reset()
    st, rng, differs = eng.state, np.random.default_rng(0), False
    for _ in range(25):
        headings = st.heading.copy()
        acts = {}
        for turned in (False, True):
            st.heading[:] = rng.integers(0, 4, headings.shape) if turned else headings
            for follow in (True, False):
                acts[turned, follow] = make_window_planner(name, seed=0, follow_heading=follow).act(eng)
        st.heading[:] = headings
        assert np.array_equal(acts[False, False], acts[True, False])
        differs |= not np.array_equal(acts[False, True], acts[True, True])
        eng.step(acts[False, False])
    assert differs  # the heading-following projection does read them


def test_without_an_allowed_path_cell_the_window_cell_nearest_to_the_goal_is_taken():
    belief, pos = _belief(MAP)
    goal = (1, 10)
    # the path heading east is masked cell by cell: fall back to the allowed window cell with the
    # shortest path to the goal, the corner (4, 4) (6 steps from the robot on a shortest path)
    mask = _mask_out((1, 2), (1, 3), (1, 4))
    assert _cell(_project(belief, pos, goal, mask=mask, heading=0), pos) == (4, 4)
    # with that corner masked too, the next best: (3, 4) or (4, 3), one step farther from the goal
    mask = _mask_out((1, 2), (1, 3), (1, 4), (4, 4))
    assert _cell(_project(belief, pos, goal, mask=mask, heading=0), pos) in ((3, 4), (4, 3))


def test_unreachable_goals_mean_stay():
    belief, pos = _belief(MAP)
    walled = belief.copy()
    walled[5, 6] |= OCCUPIED  # close the gap: the right room is cut off
    walled[6, 1:6] |= OCCUPIED  # and the unexplored corridor below
    assert _project(walled, pos, (1, 10)) == 24


def test_other_robots_block_paths_and_unknown_cells_are_free():
    layout = MAP.replace("#.............#", "#.....o.......#")  # a teammate stands in the gap
    belief, pos = _belief(layout)
    assert _project(belief, pos, (1, 10)) == 24  # cut off: stay
    # open the unexplored bottom row through column 6: reachable again, around the teammate
    belief, pos = _belief(layout.replace("#?????#....o..#", "#??????....o..#"))
    # around the teammate (5, 6) through row 6: heading east, the path runs along row 1 to (1, 4)
    # and then down; heading south it runs down column 1 past the window
    assert _cell(_project(belief, pos, (1, 10), heading=1), pos) == (4, 1)


@pytest.mark.parametrize("name", ["nearest", "rrt"])
def test_window_planners_rescue_like_the_cell_planners(name):
    cfg = make_config("task1")
    rescued = {}
    for mode, planner in (("cell", make_planner(name, 0)), ("window", make_window_planner(name, 0))):
        eng = EventEngine(cfg, 16, 0, goal_mode=mode)
        eng.reset()
        while not eng.state.done.all():
            eng.step(planner.act(eng))  # raises if a projected action were masked
        rescued[mode] = float((eng.state.rescue_tick >= 0).mean())
    assert rescued["window"] >= rescued["cell"] - 1 / 16
    assert rescued["window"] >= 0.9


def test_a_window_planner_refuses_a_cell_mode_engine():
    eng = EventEngine(make_config("task1"), 1, 0, goal_mode="cell")
    eng.reset()
    with pytest.raises(ValueError, match="goal_mode='window'"):
        make_window_planner("nearest").act(eng)
