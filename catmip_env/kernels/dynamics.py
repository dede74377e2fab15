"""Per-tick world dynamics as numba kernels over a batch of worlds (docs/design.md#world-rules).

One call of :func:`tick` advances every live world by one tick:

1. move      robots in id order execute their primitive action (every ``ticks_per_action`` ticks);
2. sense     each robot marks its line-of-sight view explored in its own belief;
3. comms     links are drawn (or full communication), neighbourhoods = connected components;
4. merge     beliefs are OR-merged inside every neighbourhood;
5. mission   first target knowledge and success (a target-aware rescuer next to the target), rewards;
6. noise     the occupancy map each robot *uses* this tick is redrawn (if ``slam_noise > 0``).

The entry kernels (:func:`tick`, :func:`perceive_at_reset`) take the world state as one value ``s``
(:class:`~catmip_env.kernels.state.KernelState`, the arrays of :class:`~.state.WorldState`) and the
constants of the run as one :class:`Rules` value. They unpack ``s`` once per call and hand the per-world
steps the arrays they use: numba reference-counts every array of a namedtuple each time the tuple is
passed or read, which done per world and tick more than doubled the time of a tick.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from catmip_env.config import EnvConfig
from catmip_env.constants import (
    CLUE,
    EXPLORED,
    FORWARD,
    FREE,
    OCCUPIED,
    STEP_COL,
    STEP_ROW,
    TARGET_BIT,
    TURN_LEFT,
    TURN_RIGHT,
)
from catmip_env.kernels.comms import draw_neighbourhoods, merge_beliefs, remember
from catmip_env.kernels.rng import uniform
from catmip_env.kernels.sensing import RAY_NBLOCK, VIEW_BLOCKERS, VIEW_OFFSETS, sense_robot
from catmip_env.kernels.state import KernelState


class Rules(NamedTuple):
    """The constants of a run that the kernels read, as one value (built once per engine)."""

    horizon_ticks: int  # ticks per episode
    slam_noise: float  # probability that an explored cell's used occupancy is flipped, 0 = none
    step_reward: float  # per successful forward move
    collision_penalty: float  # per forward move into a wall, obstacle or the target
    find_reward: float  # to every robot when the target first becomes known (times the time scale)
    rescue_reward: float  # to every robot on success (times the time scale)
    max_ma_ticks: int  # macro level: ticks after which a macro-action ends
    t_min: int  # macro level: activation rule (t_min, t_max)
    t_max: int
    synchronous: bool  # macro level: everyone decides every max_ma_ticks ticks
    gamma: float  # macro level: per-tick discount of ma_rewards
    view_offsets: np.ndarray  # (4, K, 2) sensing.VIEW_OFFSETS
    view_blockers: np.ndarray  # (4, K, M, 4) sensing.VIEW_BLOCKERS
    ray_nblock: np.ndarray  # (K,) sensing.RAY_NBLOCK

    @classmethod
    def of(cls, cfg: EnvConfig, gamma: float = 1.0) -> Rules:
        """The rules of ``cfg`` (``gamma``: the event engine's discount)."""
        t_min, t_max = cfg.activation
        return cls(
            horizon_ticks=int(cfg.horizon_ticks),
            slam_noise=float(cfg.slam_noise),
            step_reward=float(cfg.step_reward),
            collision_penalty=float(cfg.collision_penalty),
            find_reward=float(cfg.find_reward),
            rescue_reward=float(cfg.rescue_reward),
            max_ma_ticks=int(cfg.max_ma_ticks),
            t_min=int(t_min),
            t_max=int(t_max),
            synchronous=bool(cfg.synchronous),
            gamma=float(gamma),
            view_offsets=VIEW_OFFSETS,
            view_blockers=VIEW_BLOCKERS,
            ray_nblock=RAY_NBLOCK,
        )


@njit(cache=True)
def move_robots(
    b: int,
    t0: int,  # 0-based index of the tick being executed
    grid: np.ndarray,  # (B, H, W) uint8
    pos: np.ndarray,  # (B, N, 2) int64
    heading: np.ndarray,  # (B, N) int64
    speed: np.ndarray,  # (B, N) int64 ticks per action of each robot
    actions: np.ndarray,  # (B, N) int64 primitive actions
    step_reward: float,
    collision_penalty: float,
    rewards: np.ndarray,  # (B, N) float64, accumulated into
    moves: np.ndarray,  # (B, N) int64 successful forward moves this episode, incremented
    collisions: np.ndarray,  # (B, N) int64 forward moves into walls/obstacles/target, incremented
) -> None:
    n = pos.shape[1]
    for i in range(n):
        if t0 % speed[b, i] != 0:
            continue  # a slow robot holds its previous command on this tick
        a = actions[b, i]
        if a == TURN_LEFT:
            heading[b, i] = (heading[b, i] + 3) % 4
        elif a == TURN_RIGHT:
            heading[b, i] = (heading[b, i] + 1) % 4
        elif a == FORWARD:
            h = heading[b, i]
            r = pos[b, i, 0] + STEP_ROW[h]
            c = pos[b, i, 1] + STEP_COL[h]
            g = grid[b, r, c]
            if g != FREE and g != CLUE:
                rewards[b, i] += collision_penalty
                collisions[b, i] += 1
                continue
            blocked = False
            for j in range(n):
                if j != i and pos[b, j, 0] == r and pos[b, j, 1] == c:
                    blocked = True
                    break
            if not blocked:
                pos[b, i, 0] = r
                pos[b, i, 1] = c
                rewards[b, i] += step_reward
                moves[b, i] += 1


@njit(cache=True)
def draw_used_occupancy(
    b: int, belief: np.ndarray, pos: np.ndarray, noise: float, rng: np.ndarray, used: np.ndarray
) -> None:
    """Occupancy each robot uses this tick: its belief's OCCUPIED bit, each explored cell flipped
    with probability ``noise`` (geometric skipping: one draw per flip), its own cell always free.

    Only written when ``noise > 0``; without noise the used map is the belief itself.
    """
    if noise <= 0.0:
        return  # consumers read the belief's OCCUPIED bit directly
    n, h, w = belief.shape[1], belief.shape[2], belief.shape[3]
    hw = h * w
    log_q = math.log(1.0 - noise) if noise < 1.0 else -1e300
    for i in range(n):
        for r in range(h):
            for c in range(w):
                used[b, i, r, c] = 1 if belief[b, i, r, c] & OCCUPIED else 0
        k = -1
        while True:
            u = uniform(rng, b)
            k += 1 + int(math.log(1.0 - u) / log_q) if noise < 1.0 else 1
            if k >= hw:
                break
            r, c = k // w, k % w
            if belief[b, i, r, c] & EXPLORED:
                used[b, i, r, c] ^= 1
        used[b, i, pos[b, i, 0], pos[b, i, 1]] = 0


@njit(cache=True)
def sense_all(
    b: int,
    grid: np.ndarray,
    pos: np.ndarray,
    heading: np.ndarray,
    belief: np.ndarray,
    view_offsets: np.ndarray,
    view_blockers: np.ndarray,
    ray_nblock: np.ndarray,
) -> None:
    for i in range(pos.shape[1]):
        sense_robot(
            grid,
            belief,
            b,
            i,
            pos[b, i, 0],
            pos[b, i, 1],
            heading[b, i],
            view_offsets,
            view_blockers,
            ray_nblock,
        )


@njit(cache=True)
def mission_update(
    b: int,
    tick_1b: int,  # 1-based tick index t (0 at reset)
    horizon: int,
    target: np.ndarray,  # (B, 2)
    pos: np.ndarray,
    can_rescue: np.ndarray,  # (B, N) bool
    belief: np.ndarray,
    found_tick: np.ndarray,  # (B,) int64, -1 until the target is known to anyone
    informed_tick: np.ndarray,  # (B,) int64, -1 until a robot that can rescue knows the target
    rescue_tick: np.ndarray,  # (B,) int64, -1 until success
    find_reward: float,
    rescue_reward: float,
    rewards: np.ndarray,
) -> bool:
    """Team rewards for first target knowledge and success; returns whether the mission succeeded."""
    n = pos.shape[1]
    tr, tc = target[b, 0], target[b, 1]
    scale = 1.0 - 0.9 * tick_1b / horizon
    if found_tick[b] < 0:
        for i in range(n):
            if belief[b, i, tr, tc] & TARGET_BIT:
                found_tick[b] = tick_1b
                for j in range(n):
                    rewards[b, j] += find_reward * scale
                break
    if found_tick[b] < 0:
        return False
    for i in range(n):
        if can_rescue[b, i] and belief[b, i, tr, tc] & TARGET_BIT:
            if informed_tick[b] < 0:
                informed_tick[b] = tick_1b
            if abs(pos[b, i, 0] - tr) + abs(pos[b, i, 1] - tc) == 1:
                rescue_tick[b] = tick_1b
                for j in range(n):
                    rewards[b, j] += rescue_reward * scale
                return True
    return False


@njit(cache=True)
def perceive(
    b: int,
    tick_1b: int,
    grid: np.ndarray,
    target: np.ndarray,
    pos: np.ndarray,
    heading: np.ndarray,
    can_rescue: np.ndarray,
    belief: np.ndarray,
    comp: np.ndarray,
    rng: np.ndarray,
    used_occ: np.ndarray,
    found_tick: np.ndarray,
    informed_tick: np.ndarray,
    rescue_tick: np.ndarray,
    rewards: np.ndarray,
    horizon: int,
    comm_sigma: float,
    noise: float,
    find_reward: float,
    rescue_reward: float,
    view_offsets: np.ndarray,
    view_blockers: np.ndarray,
    ray_nblock: np.ndarray,
) -> bool:
    """Steps 2-6 of a tick for world b (also run at reset, with t = 0). Returns success."""
    sense_all(b, grid, pos, heading, belief, view_offsets, view_blockers, ray_nblock)
    draw_neighbourhoods(b, pos, comm_sigma, rng, comp)
    merge_beliefs(b, comp, belief)
    success = mission_update(
        b,
        tick_1b,
        horizon,
        target,
        pos,
        can_rescue,
        belief,
        found_tick,
        informed_tick,
        rescue_tick,
        find_reward,
        rescue_reward,
        rewards,
    )
    draw_used_occupancy(b, belief, pos, noise, rng, used_occ)
    return success


@njit(cache=True, nogil=True)  # threads=: chunks of worlds run at once
def perceive_at_reset(worlds: np.ndarray, s: KernelState, rules: Rules) -> None:
    """Steps 2-6 at t = 0 for the worlds in the bool mask ``worlds`` (B,); rewards (the target in view
    at t = 0) go to ``s.pending_reward``, paid with the next step."""
    grid, target, pos, heading, can_rescue = s.grid, s.target, s.pos, s.heading, s.can_rescue
    belief, comp, rng, used_occ, pending = s.belief, s.comp, s.rng, s.used_occ, s.pending_reward
    found_tick, informed_tick, rescue_tick = s.found_tick, s.informed_tick, s.rescue_tick
    comm_sigma, horizon, noise = s.comm_sigma, rules.horizon_ticks, rules.slam_noise
    find_reward, rescue_reward = rules.find_reward, rules.rescue_reward
    view_offsets, view_blockers, ray_nblock = rules.view_offsets, rules.view_blockers, rules.ray_nblock
    heard_tick, heard_pos, heard_knows, heard_goal = s.heard_tick, s.heard_pos, s.heard_knows, s.heard_goal
    for b in range(worlds.shape[0]):
        if worlds[b]:
            perceive(
                b,
                0,
                grid,
                target,
                pos,
                heading,
                can_rescue,
                belief,
                comp,
                rng,
                used_occ,
                found_tick,
                informed_tick,
                rescue_tick,
                pending,
                horizon,
                comm_sigma[b],
                noise,
                find_reward,
                rescue_reward,
                view_offsets,
                view_blockers,
                ray_nblock,
            )
            remember(b, 0, pos, comp, belief, target, heard_tick, heard_pos, heard_knows, s.goal, heard_goal)


@njit(cache=True, nogil=True)  # threads=: chunks of worlds run at once
def tick(
    live: np.ndarray,  # (B,) bool: worlds to advance (those not done)
    actions: np.ndarray,  # (B, N) int64 primitive actions
    s: KernelState,
    rules: Rules,
    rewards: np.ndarray,  # (B, N) float64 out
    terminated: np.ndarray,  # (B,) bool out
    truncated: np.ndarray,  # (B,) bool out
) -> None:
    """Advance every world with ``live[b]`` by one tick and mark the finished ones ``s.done``.

    ``rewards`` receives each live world's rewards of this tick plus any reward pending since its reset
    (which is then cleared), zero elsewhere; ``terminated`` / ``truncated`` are false for worlds not live.
    """
    # Unpacked once per call: numba reference-counts every array of a namedtuple that is passed on.
    grid, target, pos, heading, speed = s.grid, s.target, s.pos, s.heading, s.speed
    can_rescue, belief, comp, rng, used_occ = s.can_rescue, s.belief, s.comp, s.rng, s.used_occ
    ticks, moves, collisions, pending, done = s.ticks, s.moves, s.collisions, s.pending_reward, s.done
    found_tick, informed_tick, rescue_tick = s.found_tick, s.informed_tick, s.rescue_tick
    comm_sigma, heard_tick, heard_pos, heard_knows = s.comm_sigma, s.heard_tick, s.heard_pos, s.heard_knows
    goal, heard_goal = s.goal, s.heard_goal
    horizon, noise = rules.horizon_ticks, rules.slam_noise
    step_reward, collision_penalty = rules.step_reward, rules.collision_penalty
    find_reward, rescue_reward = rules.find_reward, rules.rescue_reward
    view_offsets, view_blockers, ray_nblock = rules.view_offsets, rules.view_blockers, rules.ray_nblock
    n = pos.shape[1]
    for b in range(live.shape[0]):
        terminated[b] = False
        truncated[b] = False
        if not live[b]:
            for i in range(n):
                rewards[b, i] = 0.0
            continue
        for i in range(n):
            rewards[b, i] = pending[b, i]  # the reset reward rides on the first step
            pending[b, i] = 0.0
        t0 = ticks[b]
        move_robots(
            b,
            t0,
            grid,
            pos,
            heading,
            speed,
            actions,
            step_reward,
            collision_penalty,
            rewards,
            moves,
            collisions,
        )
        success = perceive(
            b,
            t0 + 1,
            grid,
            target,
            pos,
            heading,
            can_rescue,
            belief,
            comp,
            rng,
            used_occ,
            found_tick,
            informed_tick,
            rescue_tick,
            rewards,
            horizon,
            comm_sigma[b],
            noise,
            find_reward,
            rescue_reward,
            view_offsets,
            view_blockers,
            ray_nblock,
        )
        remember(b, t0 + 1, pos, comp, belief, target, heard_tick, heard_pos, heard_knows, goal, heard_goal)
        ticks[b] = t0 + 1
        terminated[b] = success
        truncated[b] = (not success) and t0 + 1 >= horizon
        if success or truncated[b]:
            done[b] = True
