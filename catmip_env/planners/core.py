"""What every planner of ``planners.baselines`` shares: the base class that turns one robot's choice into
the batch's cell actions (with the rescue rule), the context of one robot's decision (its belief
layers, path distances, valid goals, frontier) and the fields they are built from.

A frontier is an explored free cell with an unexplored 4-neighbour (the robot's own cell excluded).
Paths: shortest 4-connected on the belief with unknown cells free and other robots blocked, as in the
controller.
"""

from __future__ import annotations

import numpy as np

from catmip_env.constants import EXPLORED, OCCUPIED, TARGET_BIT
from catmip_env.engines.events import EventEngine
from catmip_env.kernels.bfs import bfs_from

__all__ = ["Planner", "DecisionContext", "distance_field", "stream_key", "SQUARE"]

SQUARE = 15  # side of the square whose unexplored cells measure a goal's utility


class Planner:
    """Base class: ``act(engine)`` returns (B, N) cell-mode actions (only active robots' matter).

    Its random draws come from one stream per world and episode (:meth:`world_rng`: the planner's
    seed and the world's :func:`stream_key`), so a world's episode depends on its own map and decisions
    only, never on the batch it is played in: any maps played alone give the same episodes as in a
    batch of 1,000 (what a leaderboard replay checks)."""

    name = "planner"
    rescue_rule = True  # a rescuer that knows the target heads for it

    def __init__(self, seed: int = 0) -> None:
        self.seed = int(seed)
        self.rng = np.random.default_rng(seed)  # the stream of the world deciding now (world_rng)
        self._streams: dict[int, tuple[tuple[int, int], np.random.Generator]] = {}

    def world_rng(self, engine: EventEngine, b: int) -> np.random.Generator:
        """The random stream of world ``b``'s current episode (a new one when the world's episode or
        the engine's seed changes)."""
        key = stream_key(engine, b)
        held = self._streams.get(b)
        if held is None or held[0] != key:
            held = (key, np.random.default_rng([self.seed, *key]))
            self._streams[b] = held
        return held[1]

    def act(self, engine: EventEngine) -> np.ndarray:
        if engine.goal_mode != "cell":
            raise ValueError(f"planner {self.name!r} needs an EventEngine with goal_mode='cell'")
        st = engine.state
        h, w = engine.shape
        out = (st.pos[..., 0] * w + st.pos[..., 1]).astype(np.int64)  # default: stay
        live = ~st.done
        for b, i in zip(*np.nonzero(engine.active & live[:, None])):
            self.rng = self.world_rng(engine, int(b))
            ctx = DecisionContext(engine, int(b), int(i))
            goal = ctx.rescue_goal() if self.rescue_rule else None
            if goal is None:
                goal = self.choose(ctx)
            if goal is None or not ctx.valid[goal]:
                goal = ctx.own
            out[b, i] = goal[0] * w + goal[1]
        return out

    def choose(self, ctx: DecisionContext) -> tuple[int, int] | None:  # pragma: no cover - abstract
        raise NotImplementedError

    # shared choices ---------------------------------------------------------------------------
    def _pick(self, cells: np.ndarray) -> tuple[int, int] | None:
        if len(cells) == 0:
            return None
        r, c = cells[self.rng.integers(len(cells))]
        return int(r), int(c)


def stream_key(engine, b: int) -> tuple[int, ...]:
    """What keys world ``b``'s random streams: on an :class:`~catmip_env.engines.events.EventEngine`, its
    seed and the world's episode index (the streams every committed result was played with); on the view a
    policy is given, which names neither, the world's key (``engine.world.keys[b]``,
    :func:`~catmip_env.engines.world.world_key`). Either way one stream per map, whatever the batch."""
    world = engine.world
    seed = getattr(world, "base_seed", None)
    if seed is not None:
        return (int(seed), int(engine.state.episode[b]))
    return (int(world.keys[b]),)


class DecisionContext:
    """What one active robot knows at its decision: belief layers, distances, valid goals."""

    def __init__(self, engine: EventEngine, b: int, i: int) -> None:
        st = engine.state
        h, w = engine.shape
        self.engine, self.b, self.i = engine, b, i
        bel = st.belief[b, i]
        self.explored = (bel & EXPLORED) != 0
        self.occupied = (bel & OCCUPIED) != 0
        self.pos = st.pos[b]
        self.own = (int(st.pos[b, i, 0]), int(st.pos[b, i, 1]))
        blocked = self.occupied.copy()
        blocked[0, :] = blocked[-1, :] = blocked[:, 0] = blocked[:, -1] = True
        others = np.arange(len(self.pos)) != i
        blocked[self.pos[others, 0], self.pos[others, 1]] = True
        blocked[self.own] = False
        self.blocked = blocked
        self.dist = distance_field(blocked, *self.own)
        self.valid = engine.masks[b, i].reshape(h, w) != 0
        self.knows_target = bool(bel[st.target[b, 0], st.target[b, 1]] & TARGET_BIT)
        self.can_rescue = bool(st.can_rescue[b, i])
        self.target = (int(st.target[b, 0]), int(st.target[b, 1]))
        self._frontier = None

    @property
    def frontier(self) -> np.ndarray:
        """(K, 2) reachable, valid frontier cells other than the robot's own (a goal at distance 0
        would leave a robot that faces a wall staring at it forever)."""
        if self._frontier is None:
            e = self.explored
            unexplored_nb = np.zeros_like(e)
            unexplored_nb[1:, :] |= ~e[:-1, :]
            unexplored_nb[:-1, :] |= ~e[1:, :]
            unexplored_nb[:, 1:] |= ~e[:, :-1]
            unexplored_nb[:, :-1] |= ~e[:, 1:]
            f = e & ~self.occupied & unexplored_nb & (self.dist > 0) & self.valid
            self._frontier = np.argwhere(f)
        return self._frontier

    def rescue_goal(self) -> tuple[int, int] | None:
        """A rescuer that knows the target heads for the nearest reachable cell next to it."""
        if not (self.can_rescue and self.knows_target):
            return None
        tr, tc = self.target
        best, best_d = None, None
        for r, c in ((tr, tc + 1), (tr + 1, tc), (tr, tc - 1), (tr - 1, tc)):
            d = self.dist[r, c]
            if d >= 0 and self.valid[r, c] | ((r, c) == self.own) and (best_d is None or d < best_d):
                best, best_d = (r, c), d
        return best

    def unexplored_counts(self) -> np.ndarray:
        """(H, W) number of unexplored cells in the SQUARE x SQUARE box around every cell."""
        return _box_sums(~self.explored, SQUARE // 2)


def _box_sums(mask: np.ndarray, half: int) -> np.ndarray:
    h, w = mask.shape
    ii = np.zeros((h + 1, w + 1), np.int64)
    ii[1:, 1:] = np.cumsum(np.cumsum(mask, axis=0), axis=1)
    r0 = np.clip(np.arange(h) - half, 0, h)
    r1 = np.clip(np.arange(h) + half + 1, 0, h)
    c0 = np.clip(np.arange(w) - half, 0, w)
    c1 = np.clip(np.arange(w) + half + 1, 0, w)
    return ii[r1][:, c1] - ii[r0][:, c1] - ii[r1][:, c0] + ii[r0][:, c0]


def distance_field(blocked: np.ndarray, r: int, c: int) -> np.ndarray:
    h, w = blocked.shape
    dist = np.empty(h * w, np.int64)
    bfs_from(blocked, r, c, dist, np.empty(h * w, np.int64), -1)
    return dist.reshape(h, w)
