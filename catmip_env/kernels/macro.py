"""Macro-action layer as numba kernels (docs/design.md#macro-actions-and-activation): the low-level
controller, the loop that runs a world to its next decision event, and invalid-action masks.

:func:`advance` runs each live world tick by tick (controller → move → perceive → bookkeeping) until
its next decision event or the end of its episode, entirely inside numba; like :func:`dynamics.tick` it
takes the world state as one value ``s`` and the run's constants as one ``rules``. The per-robot macro
state ``mstate`` and its bookkeeping (macro-action ends, activation, goal assignment):
:mod:`~catmip_env.kernels.activation`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from catmip_env.constants import FORWARD, OCCUPIED, STAY, TURN_LEFT, TURN_RIGHT
from catmip_env.kernels.activation import (
    M_ACTIVE,
    M_ELAPSED,
    M_STANDBY,
    M_UNREACHABLE,
    activate,
    end_macro_actions,
)
from catmip_env.kernels.bfs import next_step
from catmip_env.kernels.comms import remember
from catmip_env.kernels.dynamics import Rules, move_robots, perceive
from catmip_env.kernels.rng import randint
from catmip_env.kernels.state import KernelState


@njit(cache=True, inline="always")
def _plan_map(
    b: int,
    i: int,
    pos: np.ndarray,
    belief: np.ndarray,
    used_occ: np.ndarray,
    noisy: bool,
    blocked: np.ndarray,
) -> None:
    """blocked (H, W) = the cells robot i's controller plans around: occupied in its belief (its noisy
    occupancy under SLAM noise), the map's outer ring, and the other robots' cells (never its own)."""
    n, h, w = pos.shape[1], belief.shape[2], belief.shape[3]
    for r in range(h):
        for c in range(w):
            if noisy:
                blocked[r, c] = used_occ[b, i, r, c] != 0
            else:
                blocked[r, c] = (belief[b, i, r, c] & OCCUPIED) != 0
    # the map's extent is known: its outer ring is wall even where not yet seen
    blocked[0, :] = True
    blocked[h - 1, :] = True
    blocked[:, 0] = True
    blocked[:, w - 1] = True
    for j in range(n):
        if j != i:
            blocked[pos[b, j, 0], pos[b, j, 1]] = True
    blocked[pos[b, i, 0], pos[b, i, 1]] = False


@njit(cache=True)
def controller(
    b: int,
    t0: int,
    pos: np.ndarray,
    heading: np.ndarray,
    speed: np.ndarray,
    belief: np.ndarray,
    used_occ: np.ndarray,
    noisy: bool,
    goal: np.ndarray,
    mstate: np.ndarray,
    rng: np.ndarray,
    actions: np.ndarray,  # (B, N) int64 out
    blocked: np.ndarray,  # (H, W) bool scratch
    dist: np.ndarray,
    queue: np.ndarray,
) -> None:
    """Primitive action of every robot for this tick: follow a shortest path to the goal on the
    robot's (noisy) belief with other robots as obstacles; stay on the goal and in standby.

    Unknown cells count as free, except the map's outer ring (the map's extent is known).
    """
    n = pos.shape[1]
    for i in range(n):
        actions[b, i] = STAY
        mstate[b, i, M_UNREACHABLE] = 0
        if mstate[b, i, M_STANDBY] or goal[b, i, 0] < 0 or t0 % speed[b, i] != 0:
            continue
        _plan_map(b, i, pos, belief, used_occ, noisy, blocked)
        r, c = pos[b, i, 0], pos[b, i, 1]
        d = next_step(blocked, r, c, heading[b, i], goal[b, i, 0], goal[b, i, 1], dist, queue)
        if d == -1:
            mstate[b, i, M_UNREACHABLE] = 1
        elif d < 4:
            hd = heading[b, i]
            if d == hd:
                actions[b, i] = FORWARD
            elif d == (hd + 1) % 4:
                actions[b, i] = TURN_RIGHT
            elif d == (hd + 3) % 4:
                actions[b, i] = TURN_LEFT
            else:  # 180 degrees: a seeded coin picks the side
                actions[b, i] = TURN_LEFT if randint(rng, b, 2) == 0 else TURN_RIGHT


@njit(cache=True, inline="always")
def _open_event(
    b: int,
    mstate: np.ndarray,
    pending: np.ndarray,
    tick_rewards: np.ndarray,
    event_rewards: np.ndarray,
    ma_rewards: np.ndarray,
) -> None:
    """World b's event begins: no robot decides yet, and the reward pending since the world's reset rides
    on it (paid into the event's and the macro-actions' rewards, and cleared)."""
    for i in range(mstate.shape[1]):
        mstate[b, i, M_ACTIVE] = 0
        event_rewards[b, i] = pending[b, i]
        ma_rewards[b, i] += pending[b, i]
        pending[b, i] = 0.0
        tick_rewards[b, i] = 0.0


@njit(cache=True, inline="always")
def _credit_tick(
    b: int,
    tick_rewards: np.ndarray,
    gamma: float,
    mstate: np.ndarray,
    event_rewards: np.ndarray,
    ma_rewards: np.ndarray,
) -> None:
    """Move world b's rewards of this tick into the event's and, discounted by the ticks since each
    robot's activation, into its macro-action's (``tick_rewards`` is zero again for the next tick)."""
    for i in range(tick_rewards.shape[1]):
        r = tick_rewards[b, i]
        event_rewards[b, i] += r
        ma_rewards[b, i] += r * gamma ** mstate[b, i, M_ELAPSED]
        tick_rewards[b, i] = 0.0


@njit(cache=True, nogil=True)  # threads=: chunks of worlds run at once
def advance(
    live: np.ndarray,  # (B,) bool worlds to run (those not done)
    s: KernelState,
    rules: Rules,
    limit: int,  # pause a world after this many ticks without an event (0: no limit)
    mstate: np.ndarray,  # (B, N, M_FIELDS) int64 macro state
    actions: np.ndarray,  # (B, N) int64 scratch for the controller's primitive actions
    tick_rewards: np.ndarray,  # (B, N) float64 scratch
    event_rewards: np.ndarray,  # (B, N) float64 out: rewards of this call (zero for worlds not live)
    ma_rewards: np.ndarray,  # (B, N) float64 discounted return since each robot's activation
    event_ticks: np.ndarray,  # (B,) int64 out: ticks run in this call
    terminated: np.ndarray,  # (B,) bool out
    truncated: np.ndarray,  # (B,) bool out
) -> None:
    """Run every live world until its next decision event (some robot activates), the end of its
    episode (``s.done`` is then set), or (with a tick limit) ``limit`` ticks. A reward pending since
    the world's reset is paid first (and cleared)."""
    # Unpacked once per call: numba reference-counts every array of a namedtuple that is passed on.
    grid, target, pos, heading, speed, goal = s.grid, s.target, s.pos, s.heading, s.speed, s.goal
    can_rescue, belief, comp, rng, used_occ = s.can_rescue, s.belief, s.comp, s.rng, s.used_occ
    ticks, moves, collisions, pending, done = s.ticks, s.moves, s.collisions, s.pending_reward, s.done
    found_tick, informed_tick, rescue_tick = s.found_tick, s.informed_tick, s.rescue_tick
    heard_tick, heard_pos, heard_knows, heard_goal = s.heard_tick, s.heard_pos, s.heard_knows, s.heard_goal
    horizon, max_ma, t_min, t_max = rules.horizon_ticks, rules.max_ma_ticks, rules.t_min, rules.t_max
    comm_sigma, noise, gamma, sync = s.comm_sigma, rules.slam_noise, rules.gamma, rules.synchronous
    step_r, coll_r = rules.step_reward, rules.collision_penalty
    find_r, rescue_r = rules.find_reward, rules.rescue_reward
    view_offsets, view_blockers, ray_nblock = rules.view_offsets, rules.view_blockers, rules.ray_nblock
    blocked = np.zeros(belief.shape[2:], np.bool_)  # the controller's scratch: its map, BFS distances, queue
    dist = np.empty(blocked.size, np.int64)
    queue = np.empty(blocked.size, np.int64)
    for b in range(live.shape[0]):
        terminated[b] = False
        truncated[b] = False
        event_ticks[b] = 0
        if not live[b]:
            event_rewards[b, :] = 0.0
            continue
        _open_event(b, mstate, pending, tick_rewards, event_rewards, ma_rewards)
        while True:
            t0 = ticks[b]
            t1 = t0 + 1  # the tick this step reaches
            controller(
                b,
                t0,
                pos,
                heading,
                speed,
                belief,
                used_occ,
                noise > 0.0,
                goal,
                mstate,
                rng,
                actions,
                blocked,
                dist,
                queue,
            )
            move_robots(
                b, t0, grid, pos, heading, speed, actions, step_r, coll_r, tick_rewards, moves, collisions
            )
            success = perceive(
                b,
                t1,
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
                tick_rewards,
                horizon,
                comm_sigma[b],
                noise,
                find_r,
                rescue_r,
                view_offsets,
                view_blockers,
                ray_nblock,
            )
            remember(b, t1, pos, comp, belief, target, heard_tick, heard_pos, heard_knows, goal, heard_goal)
            ticks[b] = t1
            event_ticks[b] += 1
            _credit_tick(b, tick_rewards, gamma, mstate, event_rewards, ma_rewards)
            end_macro_actions(b, pos, goal, target, belief, mstate, rng, max_ma, t_min, t_max)
            terminated[b] = success
            truncated[b] = not success and t1 >= horizon
            done[b] = success or truncated[b]  # live worlds are those not done
            if done[b] or activate(b, t1, comp, mstate, t_min, sync, max_ma):
                break  # the episode ended, or some robot decides: a decision event
            if limit > 0 and event_ticks[b] >= limit:
                break  # paused between events (rendering, tick-level inspection)


@njit(cache=True, inline="always")
def _goal_valid(
    b: int, i: int, r: int, c: int, belief: np.ndarray, pos: np.ndarray, comp: np.ndarray
) -> bool:
    h, w = belief.shape[2], belief.shape[3]
    if r < 1 or c < 1 or r > h - 2 or c > w - 2:
        return False
    if belief[b, i, r, c] & OCCUPIED:
        return False
    for j in range(pos.shape[1]):
        if j != i and comp[b, j] == comp[b, i] and pos[b, j, 0] == r and pos[b, j, 1] == c:
            return False
    # all in-bounds 4-neighbours known occupied: a pocket no path enters
    if (
        (belief[b, i, r - 1, c] & OCCUPIED)
        and (belief[b, i, r + 1, c] & OCCUPIED)
        and (belief[b, i, r, c - 1] & OCCUPIED)
        and (belief[b, i, r, c + 1] & OCCUPIED)
    ):
        return False
    return True


@njit(cache=True, nogil=True)  # threads=: chunks of worlds run at once
def action_masks(
    worlds: np.ndarray,
    cell_mode: bool,
    window: int,
    belief: np.ndarray,
    pos: np.ndarray,
    comp: np.ndarray,
    goal: np.ndarray,
    mstate: np.ndarray,
    masks: np.ndarray,  # (B, N, A) int8 out
) -> None:
    """Invalid-action masks from the clean beliefs (docs/design.md#goals-and-masks) for active robots; a
    busy robot's mask allows only its keep-goal action (window: the centre; cell: its current goal cell)."""
    h, w = belief.shape[2], belief.shape[3]
    half = window // 2
    for b in range(worlds.shape[0]):
        if not worlds[b]:
            continue
        for i in range(pos.shape[1]):
            m = masks[b, i]
            m[:] = 0
            r0, c0 = pos[b, i, 0], pos[b, i, 1]
            if not mstate[b, i, M_ACTIVE]:
                if cell_mode:
                    m[goal[b, i, 0] * w + goal[b, i, 1]] = 1
                else:
                    m[half * window + half] = 1
                continue
            if cell_mode:
                for r in range(h):
                    for c in range(w):
                        if _goal_valid(b, i, r, c, belief, pos, comp):
                            m[r * w + c] = 1
                m[r0 * w + c0] = 1
            else:
                for a in range(window * window):
                    r, c = r0 + a // window - half, c0 + a % window - half
                    if _goal_valid(b, i, r, c, belief, pos, comp):
                        m[a] = 1
                m[half * window + half] = 1
