"""Reference rows: what ``rrt-relay-coord`` would score if it knew one more thing, and the walk bound.

They read what a robot cannot know (the true target, the true map): their point is the headroom above
the planners, so they are shown on the board under the ranked table, never ranked. One line each
(:data:`REFERENCES`):

* ``news-instant``  ``rrt-relay-coord`` whose rescuers head for the target the tick any robot first sees it
                    (the news reaches every rescuer at once; the search and the walk are the planner's);
* ``target-known``  ``rrt-relay-coord`` whose rescuers head for the target from tick 0 (explorers play the
                    planner; only the walk on the rescuer's own belief remains);
* ``full-comm``     ``rrt-relay-coord`` with full communication on the setting's own maps (the maps do
                    not depend on the link range; only the link does);
* ``walk-bound``    the earliest tick a rescuer that knows the true map and target at tick 0 could stand
                    next to the target (turns cost an action, a robot acts every ``ticks_per_action``
                    ticks; teammates and sighting ignored): computed from each map, not played.

``catmip eval --method news-instant`` plays one; :func:`make_reference` builds it.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from catmip_env.constants import CLUE, FREE, STEPS
from catmip_env.engines.episode_stats import EpisodeRecords
from catmip_env.planners.baselines import RRTRelayCoord

__all__ = [
    "REFERENCES",
    "Told",
    "NewsInstant",
    "TargetKnown",
    "WalkBound",
    "make_reference",
    "walk_bound_ticks",
]


class Told(RRTRelayCoord):
    """``rrt-relay-coord`` whose rescuers act as if they knew the target once :meth:`told` says so (a
    subclass says when)."""

    def told(self, ctx) -> bool:
        raise NotImplementedError

    def choose(self, ctx):
        if ctx.can_rescue and not ctx.knows_target and self.told(ctx):
            ctx.knows_target = True  # the rescue rule's goal, from the rescuer's own belief
            goal = ctx.rescue_goal()
            ctx.knows_target = False
            if goal is not None:
                return goal
        return super().choose(ctx)


class NewsInstant(Told):
    name = "news-instant"

    def told(self, ctx) -> bool:
        return bool(ctx.engine.state.found_tick[ctx.b] >= 0)


class TargetKnown(Told):
    name = "target-known"

    def told(self, ctx) -> bool:
        return True


def walk_bound_ticks(engine) -> np.ndarray:
    """(B,) the walk bound of each world the engine was just reset to: the fewest ticks for any robot that
    can rescue to stand on a free cell 4-adjacent to the target, along the true map from its start
    pose (a turn or a step is an action; a robot acts every ``speed`` ticks, so ``a`` actions end at tick
    ``speed * (a - 1) + 1``); -1 where no rescuer can get there."""
    st = engine.state
    out = np.full(engine.num_worlds, -1, np.int64)
    for b in range(engine.num_worlds):
        passable = (st.grid[b] == FREE) | (st.grid[b] == CLUE)
        tr, tc = (int(x) for x in st.target[b])
        goal = {(tr + dr, tc + dc) for dr, dc in STEPS}
        best = None
        for i in np.flatnonzero(st.can_rescue[b]):
            start = (int(st.pos[b, i, 0]), int(st.pos[b, i, 1]), int(st.heading[b, i]))
            actions = _actions_to(passable, start, goal)
            if actions is not None:
                tick = int(st.speed[b, i]) * (actions - 1) + 1 if actions else 0
                best = tick if best is None else min(best, tick)
        if best is not None:
            out[b] = best
    return out


def _actions_to(passable: np.ndarray, start: tuple[int, int, int], goal: set) -> int | None:
    """Breadth-first over (row, col, heading): the fewest turns and steps from ``start`` to a cell of
    ``goal``; None if none can be reached."""
    seen = {start: 0}
    queue = deque([start])
    while queue:
        r, c, h = state = queue.popleft()
        d = seen[state]
        if (r, c) in goal:
            return d
        nxt = [(r, c, (h + 1) % 4), (r, c, (h + 3) % 4)]
        rr, cc = r + STEPS[h][0], c + STEPS[h][1]
        if passable[rr, cc]:
            nxt.append((rr, cc, h))
        for s in nxt:
            if s not in seen:
                seen[s] = d + 1
                queue.append(s)
    return None


class WalkBound:
    """The walk bound as a policy that plays nothing: :meth:`bound_records` gives each world's episode
    record with the bound as its rescue tick (found and informed at tick 0, nothing explored, no
    decisions), -1 past the horizon."""

    name = "walk-bound"

    def __init__(self, seed: int = 0) -> None:
        self.seed = int(seed)  # unused: the bound draws nothing

    def act(self, engine):
        raise TypeError("walk-bound is computed from the maps (bound_records), not played")

    def bound_records(self, engine) -> EpisodeRecords:
        st, b, n = engine.state, engine.num_worlds, engine.num_robots
        ticks = walk_bound_ticks(engine)
        ticks[ticks > engine.cfg.horizon_ticks] = -1
        zero = np.zeros(b, np.int64)
        return EpisodeRecords(
            rescue_tick=ticks,
            found_tick=zero.copy(),
            informed_tick=zero.copy(),
            explored_fraction=np.zeros(b),
            ticks=np.where(ticks >= 0, ticks, engine.cfg.horizon_ticks).astype(np.int64),
            events=zero.copy(),
            decisions=np.zeros((b, n), np.int64),
            stalls=np.zeros((b, n), np.int64),
            cls=st.cls.astype(np.int64),
        )


REFERENCES = {
    "news-instant": (NewsInstant, None, "rrt-relay-coord; news of the target reaches every rescuer at once"),
    "target-known": (TargetKnown, None, "rrt-relay-coord; rescuers know the target from tick 0"),
    "full-comm": (RRTRelayCoord, {"comm_sigma": None}, "rrt-relay-coord with full communication"),
    "walk-bound": (WalkBound, None, "true map and target known at tick 0: the walk alone, not played"),
}
"""name -> (policy class, what it sets of the env config or None, its definition in one line)."""


def make_reference(name: str, seed: int = 0):
    """(policy, what it sets of the env config or None) of the reference row ``name``."""
    try:
        cls, needs, _ = REFERENCES[name]
    except KeyError:
        raise ValueError(f"unknown reference {name!r}; choose one of {sorted(REFERENCES)}") from None
    return cls(seed=seed), (dict(needs) if needs else None)
