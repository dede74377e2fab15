"""Classical planning baselines, choosing goals in cell mode for the active robots.

All planners share the low-level controller and activation rules of the env; they differ only in
which goal an active robot picks from its own clean belief (docs/design.md#planning-baselines):

* ``nearest``          the reachable frontier with the smallest path distance (seeded tie-break);
* ``utility``          the reachable frontier with the most unexplored cells in the 15x15 square
                       around it (ties: nearer, then seeded);
* ``rrt``              an RRT grown over the known map (step 0.5 cell, <= 10,000 iterations); samples
                       landing in unexplored space are exploration targets (<= 500), clustered
                       (8-connected cells); score = unexplored fraction of the 15x15 square around a
                       cluster - path distance / farthest reachable distance; the best cluster wins;
* ``rrt-relay``       RRT (``nearest-relay``: Nearest), and an explorer that knows the target carries
                       it to the nearest rescuer it last had news of without it (toward the cell it
                       was last heard of, from the robot's own memory, ``WorldState.heard_*``); one
                       that finds that cell empty explores on. Not among the paper's baselines;
* ``rrt-relay-heading`` the same, toward where that rescuer should be by now: moved from that cell
                       toward the goal it was heading for (``heard_goal``, ``comms.estimated_cells``);
* ``rrt-relay-coord``  ``rrt-relay-heading`` whose robots spread out while the target is unknown: a
                       cluster's score loses 0.5 for each teammate heading within 7 cells of it (linearly
                       less farther away; the goals the robot last heard of, ``heard_goal``);
* ``apf``              an artificial potential field: attraction to every frontier cluster (weight =
                       cluster size / (1 + path distance)), repulsion from teammates within radius 5,
                       greedy descent from the robot; stops at a frontier or a local minimum;
* ``random-frontier``  a uniformly drawn reachable frontier (floor);
* ``random-rescue``    a uniformly drawn valid goal inside the robot's 7x7 window, with the rescue rule;
* ``random-uniform``   the same without the rescue rule: no skill at all (the floor of a learner).

A frontier is an explored free cell with an unexplored 4-neighbour (the robot's own cell excluded).
The rescue rule: a rescuer that knows the target heads for the reachable cell next to it with the
shortest path. Paths: shortest 4-connected on the belief with unknown cells free and other robots
blocked, as in the controller. Planners are seeded and deterministic.

>>> eng = EventEngine(PRESETS["task1"], num_worlds=8, seed=0, goal_mode="cell")
>>> planner = make_planner("nearest", seed=0)
>>> eng.reset()
>>> while not eng.state.done.all():
...     eng.step(planner.act(eng))
"""

from __future__ import annotations

import numpy as np

from catmip_env.constants import STEPS
from catmip_env.engines.events import EventEngine
from catmip_env.kernels.comms import estimated_cells
from catmip_env.planners.core import SQUARE, DecisionContext, Planner, distance_field
from catmip_env.planners.rrt import cluster_goals, grow_rrt, label8

__all__ = ["PLANNERS", "RRT", "RRTRelay", "RRTRelayCoord", "RRTRelayHeading", "Relay", "make_planner"]

REPULSION_RADIUS = 5.0
RRT_STEP = 0.5
RRT_ITERATIONS = 10_000
RRT_TARGETS = 500
CROWDING = 0.5  # rrt-relay-coord: a teammate's goal on a cluster costs it this much of its score
CROWDING_RADIUS = 7.0  # cells (half the utility square's side)


class Nearest(Planner):
    name = "nearest"

    def choose(self, ctx):
        f = ctx.frontier
        if len(f) == 0:
            return None
        d = ctx.dist[f[:, 0], f[:, 1]]
        return self._pick(f[d == d.min()])


class Utility(Planner):
    name = "utility"

    def choose(self, ctx):
        f = ctx.frontier
        if len(f) == 0:
            return None
        u = ctx.unexplored_counts()[f[:, 0], f[:, 1]]
        best = f[u == u.max()]
        d = ctx.dist[best[:, 0], best[:, 1]]
        return self._pick(best[d == d.min()])


class RandomFrontier(Planner):
    name = "random-frontier"

    def choose(self, ctx):
        return self._pick(ctx.frontier)


class RandomWindow(Planner):
    name = "random-rescue"

    def choose(self, ctx):
        half = ctx.engine.cfg.window // 2
        r, c = ctx.own
        win = np.zeros_like(ctx.valid)
        win[max(r - half, 0) : r + half + 1, max(c - half, 0) : c + half + 1] = True
        return self._pick(np.argwhere(win & ctx.valid))


class UniformWindow(RandomWindow):
    name = "random-uniform"
    rescue_rule = False


# -- RRT --------------------------------------------------------------------------------------------


class RRT(Planner):
    name = "rrt"

    def choose(self, ctx):
        goals = self.cluster_goals(ctx, self.rng)
        if len(goals) == 0:
            return None
        best = goals[int(np.argmax(goals[:, 2]))]  # the first best cluster
        return int(best[0]), int(best[1])

    def cluster_goals(self, ctx: DecisionContext, rng: np.random.Generator) -> np.ndarray:
        """(K, 3) the goal (row, column) and score of each cluster of exploration targets of a tree grown
        from ``rng``'s draws (``rrt.cluster_goals``; empty if none)."""
        h, w = ctx.explored.shape
        targets = np.empty((RRT_TARGETS, 2), np.int64)
        u = rng.random((RRT_ITERATIONS, 2))
        own = float(ctx.own[0]), float(ctx.own[1])
        n = grow_rrt(ctx.explored, ctx.occupied, *own, u, RRT_STEP, RRT_TARGETS, targets)
        if n == 0:
            return np.empty((0, 3))
        cells = np.zeros((h, w), bool)
        cells[targets[:n, 0], targets[:n, 1]] = True
        counts = ctx.unexplored_counts() / float(SQUARE * SQUARE)
        crowding = self.crowding(ctx)
        if crowding is not None:
            counts = counts - crowding
        return cluster_goals(cells, counts, ctx.dist, ctx.valid)

    def crowding(self, ctx: DecisionContext) -> np.ndarray | None:
        """(H, W) what a cluster there loses to the robot's teammates (none: RRT ignores them)."""
        return None


class Relay:
    """The relay rule on top of a planner (``class NearestRelay(Relay, Nearest)``): an explorer that knows
    the target carries it to the nearest rescuer it last had news of without it (the valid goal nearest
    to where that rescuer was then, ties by path distance); at that cell with the rescuer gone, it gives
    that news up until newer news of the rescuer. Otherwise the planner chooses. It reads the robot's own
    memory of its teammates (``WorldState.heard_*``). With ``heading`` the rescuer is looked for where it
    should be by now, moved from where it was toward the goal it was heading for (``estimated_cells``)."""

    heading = False

    def __init__(self, seed: int = 0) -> None:
        super().__init__(seed)
        self._given_up: dict[int, tuple[int, set]] = {}  # world -> (episode, {(robot, rescuer, news tick)})
        self.relayed = np.zeros((0, 0), bool)  # (B, N): the robots whose goal the relay rule chose last act

    def act(self, engine: EventEngine) -> np.ndarray:
        self.relayed = np.zeros((engine.num_worlds, engine.num_robots), bool)
        return super().act(engine)

    def choose(self, ctx):
        cell = self._rescuer_to_tell(ctx)
        if cell is None:
            return super().choose(ctx)
        self.relayed[ctx.b, ctx.i] = True
        cells = np.argwhere(ctx.valid & (ctx.dist > 0))
        if len(cells) == 0:
            return None
        key = ((cells - cell) ** 2).sum(axis=1) * (ctx.dist.size + 1) + ctx.dist[cells[:, 0], cells[:, 1]]
        r, c = cells[np.argmin(key)]
        return int(r), int(c)

    def _rescuer_to_tell(self, ctx: DecisionContext) -> np.ndarray | None:
        """Where the nearest rescuer this explorer last had news of, without the target, was then."""
        if ctx.can_rescue or not ctx.knows_target:
            return None
        st, b, i = ctx.engine.state, ctx.b, ctx.i
        episode, given_up = self._given_up.get(b, (None, None))
        if episode != st.episode[b]:  # a new episode forgets the last one's
            given_up = set()
            self._given_up[b] = (int(st.episode[b]), given_up)
        best, best_d = None, np.inf
        cells = st.heard_pos[b, i]
        if self.heading:  # this robot's row of the estimates only
            row = slice(i, i + 1)
            news = (st.heard_tick[b, row], st.heard_pos[b, row], st.heard_goal[b, row])
            cells = estimated_cells(*news, st.ticks[b], st.speed[b])[0]
        for j in np.flatnonzero(st.can_rescue[b]):
            tick = int(st.heard_tick[b, i, j])
            key = (i, int(j), tick)
            if tick < 0 or st.heard_knows[b, i, j] or key in given_up:
                continue
            cell = cells[j]
            d = float(np.hypot(*(cell - ctx.own)))
            if d <= 1.5:  # there, and the rescuer is not: explore on until newer news of it
                given_up.add(key)
            elif d < best_d:
                best, best_d = cell, d
        return best


class RRTRelay(Relay, RRT):
    name = "rrt-relay"


class NearestRelay(Relay, Nearest):
    name = "nearest-relay"


class RRTRelayHeading(Relay, RRT):
    name = "rrt-relay-heading"
    heading = True


class RRTRelayCoord(RRTRelayHeading):
    """``rrt-relay-heading`` with coordinated exploration: while a robot does not know the target, each
    teammate whose goal it has heard of (``heard_goal``, its own memory) takes ``CROWDING`` from the score
    of a cluster at that goal, linearly less out to ``CROWDING_RADIUS`` cells (Euclidean), so that the
    team spreads over the map instead of exploring the same frontier."""

    name = "rrt-relay-coord"

    def crowding(self, ctx):
        st, b, i = ctx.engine.state, ctx.b, ctx.i
        if ctx.knows_target:
            return None
        heard = (st.heard_tick[b, i] >= 0) & (st.heard_goal[b, i, :, 0] >= 0)
        heard[i] = False
        if not heard.any():
            return None
        h, w = ctx.explored.shape
        rr, cc = np.mgrid[0:h, 0:w]
        out = np.zeros((h, w))
        for g in st.heard_goal[b, i, heard]:
            out += np.clip(1.0 - np.hypot(rr - g[0], cc - g[1]) / CROWDING_RADIUS, 0.0, None)
        return CROWDING * out


# -- APF --------------------------------------------------------------------------------------------


class APF(Planner):
    """Artificial potential field over the robot's belief (attraction to frontier clusters,
    repulsion from teammates), descended greedily from the robot's cell."""

    name = "apf"
    repulsion_gain = 2.0
    max_descent = 64

    def choose(self, ctx):
        f = ctx.frontier
        if len(f) == 0:
            return None
        h, w = ctx.explored.shape
        cells = np.zeros((h, w), bool)
        cells[f[:, 0], f[:, 1]] = True
        labels, n_clusters = label8(cells)
        potential = np.zeros((h, w))
        for k in range(1, n_clusters + 1):
            members = np.argwhere(labels == k)
            centre = members.mean(axis=0)
            m = members[np.argmin(((members - centre) ** 2).sum(axis=1))]
            d = distance_field(ctx.blocked, int(m[0]), int(m[1]))
            potential -= np.where(d >= 0, len(members) / (1.0 + np.maximum(d, 0)), 0.0)
        rr, cc = np.mgrid[0:h, 0:w]
        for j in range(len(ctx.pos)):
            if j == ctx.i or ctx.engine.state.comp[ctx.b, j] != ctx.engine.state.comp[ctx.b, ctx.i]:
                continue
            dj = np.hypot(rr - ctx.pos[j, 0], cc - ctx.pos[j, 1])
            near = dj < REPULSION_RADIUS
            potential[near] += (
                self.repulsion_gain * (1.0 / np.maximum(dj[near], 0.5) - 1.0 / REPULSION_RADIUS) ** 2
            )
        # greedy descent over reachable cells until a frontier or a local minimum
        r, c = ctx.own
        for _ in range(self.max_descent):
            if cells[r, c]:
                break
            best, best_u = None, potential[r, c]
            for dr, dc in STEPS:
                y, x = r + dr, c + dc
                if ctx.dist[y, x] >= 0 and not ctx.blocked[y, x] and potential[y, x] < best_u:
                    best, best_u = (y, x), potential[y, x]
            if best is None:
                break
            r, c = best
        if (r, c) == ctx.own:  # stuck at the start: fall back to the nearest frontier
            d = ctx.dist[f[:, 0], f[:, 1]]
            return self._pick(f[d == d.min()])
        return r, c


PLANNERS = {
    p.name: p
    for p in (
        Nearest,
        NearestRelay,
        Utility,
        RRT,
        RRTRelay,
        RRTRelayHeading,
        RRTRelayCoord,
        APF,
        RandomFrontier,
        RandomWindow,
        UniformWindow,
    )
}


def make_planner(name: str, seed: int = 0) -> Planner:
    """A planner by name: nearest, nearest-relay, utility, rrt, rrt-relay, rrt-relay-heading,
    rrt-relay-coord, apf, random-frontier, random-rescue, random-uniform."""
    try:
        return PLANNERS[name](seed=seed)
    except KeyError:
        raise ValueError(f"unknown planner {name!r}; choose one of {sorted(PLANNERS)}") from None
