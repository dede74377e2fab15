"""Planners projected into the goal window (catmip_env.window_planner): hand-drawn paths and whole
episodes against the cell-mode planners."""

import numpy as np
import pytest

from catmip_env import make_config
from catmip_env.constants import EXPLORED, OCCUPIED
from catmip_env.events import EventEngine
from catmip_env.planners import make_planner
from catmip_env.window_planner import make_window_planner, project_goal

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


def _project(belief, pos, goal, window=7, mask=None):
    h, w = belief.shape
    mask = np.ones(window * window, np.int8) if mask is None else mask
    dist, queue = np.empty(h * w, np.int64), np.empty(h * w, np.int64)
    return project_goal(belief, pos, 0, goal[0], goal[1], window, mask, dist, queue)


def _cell(action, pos, window=7):
    return (int(pos[0, 0] + action // window - window // 2), int(pos[0, 1] + action % window - window // 2))


def test_a_goal_inside_the_window_is_kept_and_the_own_cell_is_stay():
    belief, pos = _belief(MAP)
    assert _cell(_project(belief, pos, (3, 4)), pos) == (3, 4)
    assert _project(belief, pos, (1, 1)) == 24  # the centre of a 7 x 7 window


def test_a_far_goal_becomes_the_window_cell_nearest_to_it():
    belief, pos = _belief(MAP)
    # the goal is behind the wall at column 6: every path goes through the gap at (5, 6); inside the
    # window (rows and cols 1..4) the cell nearest to the goal is the corner (4, 4), 6 steps from the
    # robot on a shortest path (17 steps in all)
    goal = (1, 10)
    assert _cell(_project(belief, pos, goal), pos) == (4, 4)
    # masked, it gives way to the next best: (3, 4) or (4, 3), one step farther from the goal
    mask = np.ones(49, np.int8)
    mask[(4 - 1 + 3) * 7 + 4 - 1 + 3] = 0
    assert _cell(_project(belief, pos, goal, mask=mask), pos) in ((3, 4), (4, 3))


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
    assert _cell(_project(belief, pos, (1, 10)), pos) == (4, 4)


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
