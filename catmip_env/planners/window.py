"""Planners projected into the goal window: a classical planner's goal as an AMAT window action.

A planner (``catmip_env.planners.baselines``) picks any cell of the map; AMAT picks a goal inside the robot's
D x D window (docs/design.md#goals-and-masks). :class:`WindowPlanner` runs the planner on a window-mode
:class:`~catmip_env.engines.events.EventEngine` and turns each active robot's cell goal into a window action:

* the goal itself if it lies inside the window and is allowed by the window mask;
* otherwise the farthest allowed cell, inside the window, of the path the controller itself would
  take to the goal: a shortest path that keeps the robot's heading while it can (then E, S, W, N), so
  that a robot aiming one window at a time makes the turns a robot aiming at the goal makes, and no
  more. With ``follow_heading=False`` (method ``window-noheading:NAME``) the path ignores the robot's
  heading: its first move is the first of E, S, W, N on a shortest path, and it then goes straight
  while it can. Its goals then depend only on what AMAT observes (positions and maps, no heading), at
  the price of a turn where the robot faced another way;
* if no cell of that path inside the window is allowed, the allowed window cell with the shortest
  path to the goal (ties: the nearest to the robot); all paths on the robot's clean belief as the
  controller plans them (unknown cells free; known occupied cells, the border and other robots
  blocked);
* "stay" (the centre) if the goal is the robot's own cell or unreachable, or no window cell is nearer
  to it than the robot.

The rescue rule comes with the planner: a rescuer that knows the target heads for the reachable cell
next to it. This is the teacher of ``catmip train --warm-start`` (imitation) and, as the evaluation
method ``window:NAME``, a window-level baseline: the ceiling of imitating that planner.

>>> eng = EventEngine(PRESETS["task1"], num_worlds=8, seed=0)      # goal_mode="window"
>>> teacher = WindowPlanner(make_planner("nearest", seed=0))
>>> eng.reset()
>>> while not eng.state.done.all():
...     eng.step(teacher.act(eng))
"""

from __future__ import annotations

import numpy as np
from numba import njit

from catmip_env.constants import OCCUPIED, STEP_COL, STEP_ROW
from catmip_env.engines.events import EventEngine
from catmip_env.kernels.bfs import UNREACHED, bfs_from, downhill
from catmip_env.kernels.macro import action_masks
from catmip_env.planners.baselines import make_planner
from catmip_env.planners.core import Planner

__all__ = ["WINDOW_KINDS", "WindowPlanner", "make_window_planner", "project_goal", "window_method_name"]

WINDOW_KINDS = {"window": True, "window-noheading": False}
"""Method prefix of a window planner (``window:NAME``) -> whether its projection follows the heading."""


def window_method_name(planner: str, follow_heading: bool = True) -> str:
    """``window:PLANNER`` or ``window-noheading:PLANNER``: the method that projects as asked."""
    kind = next(k for k, follows in WINDOW_KINDS.items() if follows == bool(follow_heading))
    return f"{kind}:{planner}"


@njit(cache=True)
def project_goal(
    belief: np.ndarray,  # (H, W) uint8 the robot's belief bits
    pos: np.ndarray,  # (N, 2) int64 every robot's cell
    i: int,  # the robot
    heading: int,  # its heading (0 = E, 1 = S, 2 = W, 3 = N), or -1: none (E, S, W, N, then straight)
    goal_r: int,
    goal_c: int,
    window: int,
    window_mask: np.ndarray,  # (D * D,) allowed window actions of the robot
    dist: np.ndarray,  # (H * W) int64 scratch
    queue: np.ndarray,  # (H * W) int64 scratch
) -> int:
    """The window action for a goal anywhere on the map: the goal itself when it is inside and
    allowed; else the farthest allowed window cell of the controller's own path to it (heading first,
    then E, S, W, N among equally short moves); else the allowed window cell with the shortest path to
    the goal (ties: the one nearest the robot, then row-major); the centre ("stay") when the goal is
    the robot's own cell or unreachable, or no window cell is nearer to it than the robot."""
    h, w = belief.shape
    half = window // 2
    stay = half * window + half
    r0, c0 = pos[i, 0], pos[i, 1]
    if goal_r == r0 and goal_c == c0:
        return stay
    dr, dc = goal_r - r0, goal_c - c0
    if abs(dr) <= half and abs(dc) <= half:
        a = (dr + half) * window + dc + half
        if window_mask[a] != 0:
            return a
    blocked = (belief & OCCUPIED) != 0
    blocked[0, :] = True
    blocked[h - 1, :] = True
    blocked[:, 0] = True
    blocked[:, w - 1] = True
    for j in range(pos.shape[0]):
        if j != i:
            blocked[pos[j, 0], pos[j, 1]] = True
    blocked[r0, c0] = False
    if bfs_from(blocked, goal_r, goal_c, dist, queue, -1) == 0:
        return stay
    to_goal = dist.copy()
    if to_goal[r0 * w + c0] == UNREACHED:
        return stay
    best = _farthest_on_path(to_goal, h, w, r0, c0, heading, window, window_mask)
    if best >= 0:
        return best
    bfs_from(blocked, r0, c0, dist, queue, -1)  # dist: from the robot
    return _nearest_to_goal(to_goal, dist, h, w, r0, c0, window, window_mask)


@njit(cache=True)
def _farthest_on_path(
    to_goal: np.ndarray, h: int, w: int, r0: int, c0: int, heading: int, window: int, window_mask: np.ndarray
) -> int:
    """The farthest allowed window cell (as a window action) of the path the controller would take from
    (r0, c0) down ``to_goal`` (the heading first, then E, S, W, N among equally short moves); -1: none."""
    half = window // 2
    best, r, c, hd, g = -1, r0, c0, heading, to_goal[r0 * w + c0]
    while g > 0:
        step = downhill(to_goal, h, w, r, c, hd, g)
        if step < 0:
            break
        r, c, hd, g = r + STEP_ROW[step], c + STEP_COL[step], step, g - 1
        if abs(r - r0) > half or abs(c - c0) > half:
            break
        a = (r - r0 + half) * window + c - c0 + half
        if window_mask[a] != 0:
            best = a
    return best


@njit(cache=True)
def _nearest_to_goal(
    to_goal: np.ndarray,
    dist: np.ndarray,
    h: int,
    w: int,
    r0: int,
    c0: int,
    window: int,
    window_mask: np.ndarray,
) -> int:
    """The allowed window cell with the shortest path ``to_goal``, nearer to it than (r0, c0) (ties: the
    nearest by ``dist``, the path from the robot, then row-major); the centre ("stay") if none is."""
    half = window // 2
    stay = half * window + half
    best, best_g, best_r = stay, to_goal[r0 * w + c0], 0
    for a in range(window * window):
        r, c = r0 + a // window - half, c0 + a % window - half
        if window_mask[a] == 0 or not (0 <= r < h and 0 <= c < w):
            continue
        g, d = to_goal[r * w + c], dist[r * w + c]
        if g == UNREACHED or d == UNREACHED:
            continue
        if g < best_g or (g == best_g and best != stay and d < best_r):
            best, best_g, best_r = a, g, d
    return best


class _CellView:
    """A window-mode engine seen by a cell-mode planner: the same state, cell-mode masks."""

    goal_mode = "cell"

    def __init__(self, engine: EventEngine, masks: np.ndarray) -> None:
        self._engine, self.masks = engine, masks

    def __getattr__(self, name: str):
        return getattr(self._engine, name)


class WindowPlanner:
    """``act(engine)`` -> (B, N) window actions of ``planner``'s goals, projected (see the module)
    along the controller's path, or with ``follow_heading=False`` along a heading-free one."""

    def __init__(self, planner: Planner, follow_heading: bool = True) -> None:
        self.planner = planner
        self.follow_heading = bool(follow_heading)
        self.name = window_method_name(planner.name, self.follow_heading)
        self._cell_masks: np.ndarray | None = None
        self._scratch: tuple[np.ndarray, np.ndarray] | None = None

    def act(self, engine: EventEngine) -> np.ndarray:
        if engine.goal_mode != "window":
            raise ValueError(f"{self.name} needs an EventEngine with goal_mode='window'")
        st = engine.state
        (b_all, n), (h, w) = st.pos.shape[:2], engine.shape
        if self._cell_masks is None or self._cell_masks.shape != (b_all, n, h * w):
            self._cell_masks = np.zeros((b_all, n, h * w), np.int8)
            self._scratch = (np.empty(h * w, np.int64), np.empty(h * w, np.int64))
        live = ~st.done
        cfg, masks = engine.cfg, self._cell_masks
        action_masks(live, True, cfg.window, st.belief, st.pos, st.comp, st.goal, engine.mstate, masks)
        cells = self.planner.act(_CellView(engine, self._cell_masks))  # (B, N) flat goal cells
        out = np.full((b_all, n), engine.stay_action, np.int64)
        dist, queue = self._scratch
        for b, i in zip(*np.nonzero(engine.active & live[:, None])):
            gr, gc = divmod(int(cells[b, i]), w)
            out[b, i] = project_goal(
                st.belief[b, i],
                st.pos[b],
                int(i),
                int(st.heading[b, i]) if self.follow_heading else -1,
                gr,
                gc,
                engine.cfg.window,
                engine.masks[b, i],
                dist,
                queue,
            )
        return out


def make_window_planner(name: str, seed: int = 0, follow_heading: bool = True) -> WindowPlanner:
    """``make_planner(name, seed)`` projected into the goal window (see :class:`WindowPlanner`)."""
    return WindowPlanner(make_planner(name, seed=seed), follow_heading=follow_heading)
