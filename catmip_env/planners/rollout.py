"""A rollout teacher over ``rrt-relay-coord``: at the decisions where the record says the time goes, score a
handful of candidate goals by short simulated continuations in which every robot follows the base planner,
and play the best by the benchmark's objective (rescued by tick 100, then the rescue tick). Issue 69, item 1.

    planner = RolloutPlanner(seed=0, candidates=4, samples=4, horizon=40, when="news")
    evaluate("rollout-coord", EvalSetting("task2", "2", 0.05), 100, seed, policy=planner)

What a continuation knows: only what the deciding robot knows (its belief, which its neighbourhood
shares; where it last heard of each other teammate and of its goal), never the world's unseen truth.
Its world is rebuilt from that belief: explored cells as seen (occupied, clue, target); unexplored cells
free (as the planners' paths assume; the generator's rooms cannot be drawn conditioned on the part seen);
the target, unless the robot knows it, resampled per sample among the unexplored interior cells that fit
the clues (every known clue 8-adjacent to it, no explored free non-clue cell 8-adjacent to it), its free
unexplored neighbours made clues. The dynamics (links, SLAM noise) draw from fresh streams. ``K``
candidates x ``S`` samples are the worlds of one :class:`EventEngine`; sample ``s`` shares its target,
dynamics stream and planner streams across the candidates (common random numbers).

When it searches (``when``): ``news`` (a teammate knows the target, no rescuer does: the news-to-rescuer
phase), ``late`` (tick >= ``late_tick``, no rescuer knows it), ``both``, ``always`` (no rescuer knows it)
or ``off`` (the base planner, decision for decision). A robot under the rescue rule is never searched.
Candidates (``candidates`` at most): the base planner's goal first, then RRT's next-best clusters (the same
tree and scores as the base's) interleaved with meeting goals (the valid cell nearest to where each teammate
of the other kind should be by now, as the relay rule estimates it). The base goal wins ties. Random draws
of the search come from a stream per world and episode of its own, so the base planner's draws are those of
``rrt-relay-coord`` whatever the search does, and a map plays the same alone or in a batch.
"""

from __future__ import annotations

import time

import numpy as np

from catmip_env.constants import CLUE, CLUE_BIT, EXPLORED, OBSTACLE, OCCUPIED, TARGET, TARGET_BIT, WALL
from catmip_env.engines.events import EventEngine
from catmip_env.kernels.bfs import bfs_from
from catmip_env.kernels.comms import estimated_cells
from catmip_env.kernels.rng import seed_state
from catmip_env.planners.baselines import PLANNERS
from catmip_env.planners.core import stream_key

__all__ = ["RolloutPlanner", "WHEN", "rollout_coord", "known_world"]

BASE = PLANNERS["rrt-relay-coord"]
WHEN = ("off", "news", "late", "both", "always")
DEADLINE = 100  # the benchmark's tick: rescued by it first, then the rescue tick
TIE_WEIGHT = 0.1  # weight of the mean rescue tick (/ horizon): below 1 / samples for samples <= 9
REST_TICKS = 40  # a continuation's estimate of news + rescue after the target is found
#: the state a continuation copies from the team's (the engine view's fields; the rest is rebuilt or drawn)
COPIED = tuple(
    "pos heading cls speed can_rescue belief comp goal ticks comm_sigma heard_tick heard_pos heard_knows "
    "heard_goal".split()
)


class RolloutPlanner(BASE):
    """``rrt-relay-coord`` improved by rollouts at chosen decisions (module docstring). Knobs: ``candidates``
    (K), ``samples`` (S), ``horizon`` (ticks simulated), ``when`` and ``late_tick``. ``stats`` counts the
    searches, the decisions it changed and the seconds spent searching."""

    name = "rollout-coord"
    goal_mode = "cell"
    level = "engine"

    def __init__(
        self,
        seed: int = 0,
        candidates: int = 4,
        samples: int = 4,
        horizon: int = 40,
        when: str = "news",
        late_tick: int = 60,
    ) -> None:
        super().__init__(seed)
        if when not in WHEN:
            raise ValueError(f"unknown when {when!r}; choose one of {list(WHEN)}")
        if candidates < 1 or samples < 1 or horizon < 1:
            raise ValueError("candidates, samples and horizon must be >= 1")
        self.candidates, self.samples, self.horizon = int(candidates), int(samples), int(horizon)
        self.when, self.late_tick = when, int(late_tick)
        counts = ("searches", "changed", "sim_worlds", "rescuer_searches", "rescuer_changed")
        self.stats = {**dict.fromkeys(counts, 0), "search_s": 0.0}
        self._search_streams: dict[int, tuple[tuple[int, int], np.random.Generator]] = {}
        self._sims: dict[int, EventEngine] = {}
        self._decided: dict[int, np.ndarray] = {}

    # -- the decision loop --------------------------------------------------------------------------
    def act(self, engine) -> np.ndarray:
        self._decided = {}  # world -> (N,) goal cells chosen so far at this event (-1: not yet)
        return super().act(engine)

    def choose(self, ctx):
        goal = super().choose(ctx)  # the base planner's goal, its draws exactly as rrt-relay-coord's
        if goal is not None and self._searches(ctx):
            goal = self._search(ctx, goal)
        decided = self._decided.setdefault(ctx.b, np.full(ctx.engine.num_robots, -1, np.int64))
        if goal is not None and ctx.valid[goal]:
            decided[ctx.i] = goal[0] * ctx.engine.shape[1] + goal[1]
        return goal

    def _searches(self, ctx) -> bool:
        if self.when == "off":
            return False
        st, b = ctx.engine.state, ctx.b
        knows = _knows(st, b)
        if (knows & st.can_rescue[b]).any():  # a rescuer knows: the rescue rule plays
            return False
        news, late = bool(knows.any()), int(st.ticks[b]) >= self.late_tick
        return {"news": news, "late": late, "both": news or late, "always": True}[self.when]

    def search_rng(self, engine, b: int) -> np.random.Generator:
        """The search's own stream of world ``b``'s episode (the base planner's stays untouched)."""
        key = stream_key(engine, b)
        held = self._search_streams.get(b)
        if held is None or held[0] != key:
            held = (key, np.random.default_rng([self.seed, *key, 69]))
            self._search_streams[b] = held
        return held[1]

    # -- candidates ---------------------------------------------------------------------------------
    def candidate_goals(self, ctx, goal: tuple[int, int], rrt_state: dict | None = None) -> list:
        """Up to ``candidates`` distinct valid goals: the base's first, then RRT's next clusters
        interleaved with meeting goals."""
        ranked = self.ranked_clusters(ctx, rrt_state) if rrt_state is not None else []
        meet = self.meeting_goals(ctx)
        out = [goal]
        for pair in zip(ranked[1:] + [None] * len(meet), meet + [None] * len(ranked)):
            for g in pair:
                if g is not None and g not in out and len(out) < self.candidates:
                    out.append(g)
        return out

    def ranked_clusters(self, ctx, rrt_state: dict) -> list:
        """RRT's cluster goals best first (the base's tree, from the same draws, and its scores)."""
        rng = np.random.Generator(type(self.rng.bit_generator)())
        rng.bit_generator.state = rrt_state
        goals = self.cluster_goals(ctx, rng)
        order = np.argsort(-goals[:, 2], kind="stable")  # stable: the first best, as RRT
        return [(int(r), int(c)) for r, c in goals[order, :2]]

    def meeting_goals(self, ctx) -> list:
        """The valid goal nearest to where each teammate of the other kind (rescuer for an explorer and
        back) should be by now, from the robot's memory (``estimated_cells``), nearest teammate first."""
        st, b, i = ctx.engine.state, ctx.b, ctx.i
        row = slice(i, i + 1)
        est = estimated_cells(
            st.heard_tick[b, row], st.heard_pos[b, row], st.heard_goal[b, row], st.ticks[b], st.speed[b]
        )[0]
        cells = np.argwhere(ctx.valid & (ctx.dist > 0))
        if len(cells) == 0:
            return []
        found = []
        for j in np.flatnonzero(st.can_rescue[b] != ctx.can_rescue):
            if st.heard_tick[b, i, j] < 0:
                continue
            near = ((cells - est[j]) ** 2).sum(axis=1)
            key = near * (ctx.dist.size + 1) + ctx.dist[cells[:, 0], cells[:, 1]]
            r, c = cells[np.argmin(key)]
            found.append((float(np.hypot(*(est[j] - ctx.own))), (int(r), int(c))))
        return [g for _, g in sorted(found)]

    # -- the search ---------------------------------------------------------------------------------
    def _search(self, ctx, goal):
        t0 = time.perf_counter()
        cands = self.candidate_goals(ctx, goal, getattr(self, "_rrt_state", None))
        best = int(np.argmax(self.score(ctx, cands))) if len(cands) > 1 else 0  # the first: base's on a tie
        for kind in ("", "rescuer_") if ctx.can_rescue else ("",):  # rescuer_: a rescuer's decisions
            self.stats[kind + "searches"] += 1
            self.stats[kind + "changed"] += best != 0
        self.stats["search_s"] += time.perf_counter() - t0
        return cands[best]

    def score(self, ctx, cands: list) -> np.ndarray:
        """(K,) the candidates' value: the share of samples rescued by tick 100, then (TIE_WEIGHT) the
        mean estimated rescue tick, over S resampled continuations each."""
        engine, b, i = ctx.engine, ctx.b, ctx.i
        k, s = len(cands), self.samples
        rng = self.search_rng(engine, b)
        world = known_world(engine, b, i)
        sim = self._sim(engine.cfg, k * s)
        st, w = sim.state, engine.shape[1]
        seeds = rng.integers(2**63, size=s + 1)
        for m in range(k * s):  # sample m % s, candidate m // s
            load(sim, m, engine, b, i, world, np.random.default_rng([seeds[m % s], 1]), m % s, seeds[m % s])
        sim.refresh()
        self.stats["sim_worlds"] += k * s
        base = BASE(seed=int(seeds[-1]) % 2**32)
        given_up = getattr(self, "_given_up", {}).get(b, (None, set()))[1]
        base._given_up = {m: (m % s, set(given_up)) for m in range(k * s)}
        t_end = int(engine.state.ticks[b]) + self.horizon
        first = True
        while not st.done.all():
            a = base.act(sim)
            if first:  # this event: the candidate, and the goals chosen before it
                decided = self._decided.get(b)
                if decided is not None:
                    for j in np.flatnonzero(decided >= 0):
                        a[:, j] = decided[j]
                a[:, i] = [cands[m // s][0] * w + cands[m // s][1] for m in range(k * s)]
                first = False
            sim.step(a)
            st.done[st.ticks >= t_end] = True
        value = np.array([_value(sim, m, t_end, engine.cfg.horizon_ticks) for m in range(k * s)])
        return value.reshape(k, s).mean(axis=1)

    def _sim(self, cfg, m: int) -> EventEngine:
        sim = self._sims.get(m)
        if sim is None or sim.cfg != cfg:
            sim = EventEngine(cfg, num_worlds=m, seed=0, goal_mode="cell", invalid_action="stay")
            self._sims[m] = sim
        return sim

    def _rescuer_to_tell(self, ctx):  # the base's relay rule; it runs before RRT draws, so RRT's state
        self._rrt_state = self.rng.bit_generator.state  # is taken here (the draws RRT is about to make)
        return super()._rescuer_to_tell(ctx)


# -- what the team knows, as a world ----------------------------------------------------------------
def _knows(st, b: int) -> np.ndarray:
    """(N,) which robots of world ``b`` know the target (the engine view's target: -1 where none does)."""
    tr, tc = int(st.target[b, 0]), int(st.target[b, 1])
    if tr < 0:
        return np.zeros(st.pos.shape[1], bool)
    return (st.belief[b, :, tr, tc] & TARGET_BIT) != 0


def known_world(engine, b: int, i: int) -> dict:
    """World ``b`` as its robot ``i`` knows it: the grid rebuilt from its belief (what its neighbourhood
    shares; unexplored cells free, the outer ring wall), the target if it knows it, else the cells it
    may be in."""
    st = engine.state
    bel = np.asarray(st.belief[b, i])
    explored = (bel & EXPLORED) != 0
    grid = np.zeros(bel.shape, np.uint8)
    grid[explored & ((bel & CLUE_BIT) != 0)] = CLUE
    grid[explored & ((bel & OCCUPIED) != 0)] = OBSTACLE
    grid[[0, -1], :] = WALL
    grid[:, [0, -1]] = WALL
    target = (int(st.target[b, 0]), int(st.target[b, 1])) if _knows(st, b)[i] else None
    if target is not None:
        grid[target] = TARGET
        return {"grid": grid, "target": target, "cells": None}
    inner = np.zeros_like(explored)
    inner[1:-1, 1:-1] = True
    seen_free = explored & ((bel & OCCUPIED) == 0) & ((bel & CLUE_BIT) == 0)
    clue = explored & ((bel & CLUE_BIT) != 0)
    ok = inner & ~explored & ~_dilate8(seen_free)
    for r, c in np.argwhere(clue):  # every known clue is 8-adjacent to the target
        near = np.zeros_like(ok)
        near[r - 1 : r + 2, c - 1 : c + 2] = True
        ok &= near
    ok[st.pos[b, i, 0], st.pos[b, i, 1]] = False
    cells = np.argwhere(ok)
    if len(cells) == 0:  # beliefs that fit no cell (should not happen): any unexplored interior cell
        cells = np.argwhere(inner & ~explored)
    return {"grid": grid, "target": None, "cells": cells}


def load(
    sim: EventEngine, m: int, engine, b: int, i: int, world: dict, rng, episode: int, dyn_seed: int
) -> None:
    """World ``b`` of ``engine`` as its robot ``i`` knows it, into world ``m`` of ``sim`` (module docstring;
    a teammate never heard of keeps its state: the team starts together); ``episode`` keys the base
    planner's streams there."""
    st, src = sim.state, engine.state
    grid = world["grid"].copy()
    target = world["target"]
    if target is None:
        r, c = world["cells"][rng.integers(len(world["cells"]))]
        target = (int(r), int(c))
        box = grid[r - 1 : r + 2, c - 1 : c + 2]
        box[box == 0] = CLUE
        grid[target] = TARGET
    st.grid[m] = grid
    st.target[m] = target
    for name in COPIED:
        getattr(st, name)[m] = getattr(src, name)[b]
    away = (np.asarray(src.comp[b]) != src.comp[b, i]) & (np.asarray(src.heard_tick[b, i]) >= 0)
    st.pos[m, away], st.belief[m, away] = src.heard_pos[b, i, away], src.belief[b, i]
    heard = src.heard_goal[b, i, away]  # the goal i heard each was heading for (none: where it was)
    st.goal[m, away] = np.where(heard[:, :1] >= 0, heard, src.heard_pos[b, i, away])
    knows, mates = _knows(src, b), np.asarray(src.comp[b]) == src.comp[b, i]
    known = knows & mates if knows[i] else np.zeros_like(knows)  # who knows it, as far as i knows
    st.rng[m] = seed_state(np.random.SeedSequence([int(dyn_seed), 2]))
    st.used_occ[m if st.used_occ.shape[0] > 1 else 0] = 0
    st.moves[m] = st.collisions[m] = 0
    st.found_tick[m] = src.ticks[b] if known.any() else -1
    st.informed_tick[m] = src.ticks[b] if (known & src.can_rescue[b]).any() else -1
    st.rescue_tick[m] = -1
    st.done[m] = False
    st.episode[m] = episode
    st.pending_reward[m] = 0.0
    sim.mstate[m] = engine.mstate[b]


def _value(sim: EventEngine, m: int, t_end: int, horizon: int) -> float:
    """1{rescued by DEADLINE} - TIE_WEIGHT * rescue tick / horizon, the rescue tick estimated past the
    continuation's end: the best rescuer's path to the target if one knows it, else the relay's (half the
    knower's distance to that rescuer, then its path), else the unexplored share's exploration time."""
    st = sim.state
    tick = int(st.rescue_tick[m])
    if tick < 0:
        tick = min(int(st.ticks[m]), t_end)
        tr, tc = (int(x) for x in st.target[m])
        passable = (st.grid[m] == 0) | (st.grid[m] == CLUE)
        knows = (st.belief[m, :, tr, tc] & TARGET_BIT) != 0
        rescuers = np.flatnonzero(st.can_rescue[m])
        to_target = {int(r): _path(passable, st.pos[m, r], (tr, tc)) * int(st.speed[m, r]) for r in rescuers}
        if knows[rescuers].any():
            tick += min(to_target[int(r)] for r in rescuers if knows[r])
        elif knows.any():
            gap = min(
                float(np.hypot(*(st.pos[m, e] - st.pos[m, r]))) / 2 * int(st.speed[m, e]) + to_target[int(r)]
                for e in np.flatnonzero(knows)
                for r in rescuers
            )
            tick += int(gap)
        else:
            unexplored = ~np.bitwise_or.reduce(st.belief[m] & EXPLORED, axis=0).astype(bool)
            tick += int(unexplored[1:-1, 1:-1].mean() * horizon / 2) + REST_TICKS
    return float(tick <= DEADLINE) - TIE_WEIGHT * min(tick, horizon) / horizon


def _path(passable: np.ndarray, start, target) -> int:
    """Path length from ``start`` to a cell next to ``target`` over ``passable`` (2 (H + W) if none)."""
    h, w = passable.shape
    dist = np.empty(h * w, np.int64)
    bfs_from(~passable, int(start[0]), int(start[1]), dist, np.empty(h * w, np.int64), -1)
    dist = dist.reshape(h, w)
    tr, tc = target
    sides = ((tr, tc + 1), (tr + 1, tc), (tr, tc - 1), (tr - 1, tc))
    near = [dist[r, c] for r, c in sides if dist[r, c] >= 0]
    return min(near) if near else 2 * (h + w)


def _dilate8(mask: np.ndarray) -> np.ndarray:
    out = mask.copy()
    out[1:, :] |= mask[:-1, :]
    out[:-1, :] |= mask[1:, :]
    grown = out.copy()
    grown[:, 1:] |= out[:, :-1]
    grown[:, :-1] |= out[:, 1:]
    return grown


def rollout_coord(cfg=None, seed: int = 0, **knobs) -> RolloutPlanner:
    """The ``py:`` factory: ``--method rollout=py:catmip_env/planners/rollout.py:rollout_coord``."""
    return RolloutPlanner(seed=seed, **knobs)
