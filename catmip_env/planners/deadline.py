"""A planner that plans for the deadline: ``rrt-relay-coord`` whose explorers pick RRT's cluster by the
chance that a rescue by tick 100 starts beyond it, and whose rescuers wait near the unexplored mass.

    planner = DeadlinePlanner(seed=0, world="posterior")   # or "optimistic" (the ablation)

**Explorers** that do not know the target (and are not relaying news: the relay rule is the base's) score
each cluster ``k`` of RRT's tree (the base planner's tree and clusters, the same draws):

    score_k = sum over unexplored cells u beyond k of  m(u) * [t_rescue(u) <= DEADLINE]  /  (1 + d(k))

* "beyond k": the unexplored cells nearer (in path cells over the robot's belief, unknown cells free) to
  cluster ``k``'s goal than to any other goal;
* ``m(u)``: the probability that the target is at ``u``, normalised over every unexplored cell:
  ``optimistic`` — uniform; ``posterior`` — the generator's rules given the robot's noise-free belief: the
  room lattice (room counts per axis, each a uniform draw, and a wall line with segments present with
  ``wall_prob``), scored on the explored cells of every candidate line; the target never on a wall, an
  obstacle (density ``obstacles / S^2``) or in the 8x8 box of the team's spawn corner. Doorway zones and the
  connectivity redraw are left out (gate G1 calibrates what this buys);
* ``t_rescue(u)``: now, plus the walk to the goal and on to within ``SIGHT`` cells of ``u``, plus (without
  full communication) the walk back to within ``COMM_REACH`` of the nearest rescuer's estimated cell, plus
  that rescuer's walk to ``u`` at its speed; every walk ``TURNS`` x its path cells;
* ``d(k)``: the path cells to the goal, teammates' heard goals taking ``CROWDING`` off a cluster as the base.

When no cluster has a feasible rescue left (or none has mass), the base planner chooses. **Rescuers** that
do not know the target go to the cluster goal nearest (Euclidean, mass-weighted) to the unexplored mass.
"""

from __future__ import annotations

import numpy as np

from catmip_env.config import TARGET_EXCLUSION_BOX
from catmip_env.kernels.comms import estimated_cells
from catmip_env.kernels.mapgen import room_bounds
from catmip_env.planners.baselines import CROWDING, CROWDING_RADIUS, RRTRelayCoord
from catmip_env.planners.core import DecisionContext, distance_field

__all__ = ["DeadlinePlanner", "WORLDS", "deadline", "deadline_optimistic", "target_mass", "cluster_regions"]

DEADLINE = 100  # the benchmark's tick
SIGHT = 3  # cells: a robot sees the target within its 7x7 view ahead
COMM_REACH = 2.0  # cells: news passes within about sigma (= 2 on the benchmark's settings)
TURNS = 1.2  # ticks per path cell of a robot that acts every tick (turns included)
WALL_ON_LINE = 0.85  # P(a cell of a present wall line is a wall): wall_prob less the doorway
WORLDS = ("optimistic", "posterior")


def lattice_lines(size: int) -> list[tuple[int, ...]]:
    """The inner wall lines along one axis of every room count the generator can draw."""
    lo, hi = max(1, size // 8), max(1, size // 5)
    return [tuple(room_bounds(size, rooms)[1:-1]) for rooms in range(lo, hi + 1)]


def _line_posterior(
    occupied: np.ndarray, free: np.ndarray, size: int, p_obstacle: float, wall_prob: float
) -> np.ndarray:
    """P(each cell index along one axis is an inner wall line), from the explored cells of each index
    (``occupied`` and ``free`` (S,) counts, cells on the other axis's candidate lines left out)."""
    hyps = lattice_lines(size)
    p_wall = wall_prob * WALL_ON_LINE + (1 - wall_prob) * p_obstacle
    log_on = occupied * np.log(p_wall) + free * np.log(1 - p_wall)
    log_off = occupied * np.log(p_obstacle) + free * np.log(1 - p_obstacle)
    loglik = np.array([log_off.sum() + sum(log_on[x] - log_off[x] for x in lines) for lines in hyps])
    post = np.exp(loglik - loglik.max())
    post /= post.sum()
    on_line = np.zeros(size)
    for p, lines in zip(post, hyps):
        on_line[list(lines)] += p
    return on_line


def target_mass(ctx: DecisionContext, world: str, corner: tuple[int, int] | None) -> np.ndarray:
    """(H, W) the probability that the target is at each cell, over the unexplored interior cells
    (module docstring: ``optimistic`` uniform, ``posterior`` the generator's rules); zero elsewhere."""
    h, w = ctx.explored.shape
    unexplored = ~ctx.explored
    unexplored[0, :] = unexplored[-1, :] = unexplored[:, 0] = unexplored[:, -1] = False
    mass = unexplored.astype(float)
    if world == "posterior":
        cfg = ctx.engine.cfg
        p_obstacle = max(cfg.obstacles / float(h * w), 1e-3)
        occ, free = ctx.explored & ctx.occupied, ctx.explored & ~ctx.occupied
        rows_any = np.zeros(
            h, bool
        )  # rows that are an inner wall line of some room count, and the outer ring
        cols_any = np.zeros(w, bool)
        rows_any[[0, -1]] = cols_any[[0, -1]] = True
        for lines in lattice_lines(h):
            rows_any[list(lines)] = True
        for lines in lattice_lines(w):
            cols_any[list(lines)] = True
        # a column's evidence leaves out the cells of candidate row lines (they cross it), and vice versa
        col_p = _line_posterior(occ[~rows_any].sum(0), free[~rows_any].sum(0), w, p_obstacle, cfg.wall_prob)
        row_p = _line_posterior(
            occ[:, ~cols_any].sum(1), free[:, ~cols_any].sum(1), h, p_obstacle, cfg.wall_prob
        )
        on_line = row_p[:, None] + col_p[None, :] - row_p[:, None] * col_p[None, :]
        mass *= (1 - cfg.wall_prob * WALL_ON_LINE * on_line) * (1 - p_obstacle)
        if corner is not None:
            r0, c0 = corner
            mass[r0 : r0 + TARGET_EXCLUSION_BOX, c0 : c0 + TARGET_EXCLUSION_BOX] = 0.0
    total = mass.sum()
    return mass / total if total > 0 else mass


def cluster_regions(ctx: DecisionContext, goals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) int: the cluster each cell is nearest to in path cells from its goal (-1: none reaches it),
    and (K, H, W) the path cells from each goal (-1 unreachable), over the robot's belief."""
    fields = np.stack([distance_field(ctx.blocked, int(g[0]), int(g[1])) for g in goals])
    d = np.where(fields >= 0, fields, np.iinfo(np.int64).max)
    nearest = np.argmin(d, axis=0)
    nearest[(fields < 0).all(axis=0)] = -1
    return nearest, fields


class DeadlinePlanner(RRTRelayCoord):
    """``rrt-relay-coord`` that plans for tick 100 (module docstring); ``world``: ``posterior`` or
    ``optimistic``. ``last`` keeps the scored decision (goals, regions, masses) for the gate's records."""

    name = "rrt-relay-deadline"

    def __init__(self, seed: int = 0, world: str = "posterior", stage: bool = True) -> None:
        if world not in WORLDS:
            raise ValueError(f"unknown world {world!r}; choose one of {list(WORLDS)}")
        super().__init__(seed)
        self.world, self.stage = world, stage
        self._corners: dict[int, tuple[int, tuple[int, int]]] = {}  # world -> (episode, spawn box corner)
        self.last: dict | None = None

    def corner(self, ctx: DecisionContext) -> tuple[int, int] | None:
        """The top-left cell of the 8x8 box at the team's spawn corner, seen at the first decision."""
        st, b = ctx.engine.state, ctx.b
        episode = int(st.episode[b])
        held = self._corners.get(b)
        if held is None or held[0] != episode:
            if st.ticks[b] != 0:
                return None
            h, w = ctx.explored.shape
            mean = st.pos[b].mean(axis=0)
            r0 = 0 if mean[0] < h / 2 else h - TARGET_EXCLUSION_BOX
            c0 = 0 if mean[1] < w / 2 else w - TARGET_EXCLUSION_BOX
            held = (episode, (r0, c0))
            self._corners[b] = held
        return held[1]

    def choose(self, ctx):
        corner = self.corner(ctx)  # read at every robot's first decision
        if ctx.knows_target or self._rescuer_to_tell(ctx) is not None:
            return super().choose(ctx)  # the rescue rule and the relay rule are the base's
        if ctx.can_rescue and not self.stage:
            return super().choose(ctx)
        goals = self.cluster_goals(ctx, self.rng)
        if len(goals) == 0:
            return None
        regions, fields = cluster_regions(ctx, goals)
        mass = target_mass(ctx, self.world, corner)
        if ctx.can_rescue:
            pick = self._stage(ctx, goals, mass)
        else:
            pick = self._explore(ctx, goals, regions, fields, mass)
        if pick is None:  # nothing feasible or no mass: the base planner's best cluster
            pick = int(np.argmax(goals[:, 2]))
        return int(goals[pick, 0]), int(goals[pick, 1])

    def _explore(self, ctx, goals, regions, fields, mass) -> int | None:
        st, b = ctx.engine.state, ctx.b
        t = int(st.ticks[b])
        reach = np.maximum(fields - SIGHT, 0)  # from each goal to within sight of each cell
        to_goal = np.array([ctx.dist[int(g[0]), int(g[1])] for g in goals], float)
        sighted = t + TURNS * (to_goal[:, None, None] + reach)  # (K, H, W) ticks at which u is seen
        rescue = self._rescue_ticks(ctx)  # (H, W) ticks from the news to a rescuer standing at u
        h, w = mass.shape
        in_k = regions[None] == np.arange(len(goals))[:, None, None]
        done = sighted + rescue[None]
        feasible = in_k & (fields >= 0) & (done <= DEADLINE)
        beyond = (mass[None] * in_k).sum(axis=(1, 2))
        chance = (mass[None] * feasible).sum(axis=(1, 2))
        crowd = self._crowd_at(ctx, goals)
        score = chance * np.clip(1.0 - crowd, 0.0, None) / (1.0 + to_goal)
        self.last = {"goals": goals, "beyond": beyond, "chance": chance, "score": score, "regions": regions}
        if not (score > 0).any():
            return None
        return int(np.argmax(score))

    def _rescue_ticks(self, ctx) -> np.ndarray:
        """(H, W) ticks from the moment the explorer sees cell u to a rescuer next to u: the news carried
        to the nearest rescuer (unless communication is full) and that rescuer's walk."""
        st, b, i = ctx.engine.state, ctx.b, ctx.i
        h, w = ctx.explored.shape
        rr, cc = np.mgrid[0:h, 0:w]
        full = st.comm_sigma[b] <= 0
        row = slice(i, i + 1)
        cells = estimated_cells(
            st.heard_tick[b, row], st.heard_pos[b, row], st.heard_goal[b, row], st.ticks[b], st.speed[b]
        )[0]
        best = np.full((h, w), np.inf)
        for j in np.flatnonzero(st.can_rescue[b]):
            if st.heard_tick[b, i, j] < 0 and not full:
                continue
            cell = st.pos[b, j] if full else cells[j]
            walk = distance_field(ctx.blocked, int(cell[0]), int(cell[1])).astype(float)
            walk[walk < 0] = np.inf
            ticks = TURNS * st.speed[b, j] * walk
            if not full:
                ticks = ticks + TURNS * np.maximum(np.hypot(rr - cell[0], cc - cell[1]) - COMM_REACH, 0.0)
            best = np.minimum(best, ticks)
        return best

    def _crowd_at(self, ctx, goals) -> np.ndarray:
        """(K,) what teammates' heard goals take off each cluster (the base's crowding, at the goal)."""
        st, b, i = ctx.engine.state, ctx.b, ctx.i
        heard = (st.heard_tick[b, i] >= 0) & (st.heard_goal[b, i, :, 0] >= 0)
        heard[i] = False
        out = np.zeros(len(goals))
        for g in st.heard_goal[b, i, heard]:
            out += np.clip(
                1.0 - np.hypot(goals[:, 0] - g[0], goals[:, 1] - g[1]) / CROWDING_RADIUS, 0.0, None
            )
        return CROWDING * out

    def _stage(self, ctx, goals, mass) -> int | None:
        """A rescuer's cluster goal nearest the unexplored mass (mass-weighted Euclidean distance)."""
        if mass.sum() <= 0:
            return None
        cells = np.argwhere(mass > 0)
        weights = mass[cells[:, 0], cells[:, 1]]
        spread = np.array([(weights * np.hypot(*(cells - g[:2]).T)).sum() for g in goals])
        return int(np.argmin(spread))


def deadline(cfg=None, seed: int = 0, **knobs) -> DeadlinePlanner:
    """The ``py:`` factory: ``--method rrt-relay-deadline=py:catmip_env/planners/deadline.py:deadline``."""
    return DeadlinePlanner(seed=seed, **knobs)


def deadline_optimistic(cfg=None, seed: int = 0) -> DeadlinePlanner:
    """The ablation: the deadline objective over the optimistic world (unknown free, target uniform)."""
    return DeadlinePlanner(seed=seed, world="optimistic")
