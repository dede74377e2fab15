"""The macro state of every robot and its bookkeeping (docs/design.md#macro-actions-and-activation):
macro-action ends, asynchronous / synchronous activation, the reset's joint first decision, goal
assignment.

Per-robot macro state lives in one int64 array ``mstate (B, N, M_FIELDS)`` with the columns below; the
controller and the event loop that read it: :mod:`~catmip_env.kernels.macro`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from catmip_env.constants import TARGET_BIT
from catmip_env.kernels.rng import randint

# Columns of mstate.
M_MA_TICKS = 0  # ticks the current macro-action has run
M_STANDBY = 1  # 1 once the macro-action ended (waiting to be activated)
M_WAIT = 2  # waiting ticks w in standby
M_DEADLINE = 3  # personal deadline d ~ U{t_min .. t_max}, drawn on entering standby
M_ACTIVE = 4  # 1 if the robot decides at the current event
M_KNEW = 5  # 1 if the robot knew the target at the end of the previous tick
M_ELAPSED = 6  # ticks since the robot's last activation
M_UNREACHABLE = 7  # 1 if the controller found the goal unreachable this tick
M_FIELDS = 8


@njit(cache=True)
def end_macro_actions(
    b: int,
    pos: np.ndarray,
    goal: np.ndarray,
    target: np.ndarray,
    belief: np.ndarray,
    mstate: np.ndarray,
    rng: np.ndarray,
    max_ma_ticks: int,
    t_min: int,
    t_max: int,
) -> None:
    """Bookkeeping at the end of a tick: macro-action ends (goal reached, goal unreachable or
    occupied, target learned, time out) send robots to standby; standby robots count waiting ticks."""
    tr, tc = target[b, 0], target[b, 1]
    for i in range(pos.shape[1]):
        knows = 1 if belief[b, i, tr, tc] & TARGET_BIT else 0
        mstate[b, i, M_ELAPSED] += 1
        if mstate[b, i, M_STANDBY]:
            mstate[b, i, M_WAIT] += 1
        else:
            mstate[b, i, M_MA_TICKS] += 1
            ended = (
                (pos[b, i, 0] == goal[b, i, 0] and pos[b, i, 1] == goal[b, i, 1])
                or mstate[b, i, M_UNREACHABLE] != 0
                or (knows and not mstate[b, i, M_KNEW])
                or mstate[b, i, M_MA_TICKS] >= max_ma_ticks
            )
            if ended:
                mstate[b, i, M_STANDBY] = 1
                mstate[b, i, M_WAIT] = 0
                mstate[b, i, M_DEADLINE] = t_min + randint(rng, b, t_max - t_min + 1)
        mstate[b, i, M_KNEW] = knows


@njit(cache=True)
def activate(
    b: int, tick_1b: int, comp: np.ndarray, mstate: np.ndarray, t_min: int, sync: bool, max_ma_ticks: int
) -> bool:
    """Mark the robots that decide now (M_ACTIVE); returns whether this tick is a decision event.

    Asynchronous: inside each neighbourhood, if two or more standby robots are ready (w >= t_min) they
    all activate together; otherwise a standby robot activates alone once w reaches its deadline.
    Synchronous: everyone activates every ``max_ma_ticks`` ticks.
    """
    n = comp.shape[1]
    event = False
    if sync:
        if tick_1b % max_ma_ticks == 0:
            for i in range(n):
                mstate[b, i, M_ACTIVE] = 1
            return True
        return False
    for root in range(n):
        if comp[b, root] != root:
            continue
        ready = 0
        for i in range(root, n):
            if comp[b, i] == root and mstate[b, i, M_STANDBY] and mstate[b, i, M_WAIT] >= t_min:
                ready += 1
        for i in range(root, n):
            if comp[b, i] != root or not mstate[b, i, M_STANDBY]:
                continue
            wait = mstate[b, i, M_WAIT]
            if (ready >= 2 and wait >= t_min) or wait >= mstate[b, i, M_DEADLINE]:
                mstate[b, i, M_ACTIVE] = 1
                event = True
    return event


@njit(cache=True, nogil=True)  # threads=: chunks of worlds run at once
def start_activation(worlds: np.ndarray, target: np.ndarray, belief: np.ndarray, mstate: np.ndarray) -> None:
    """Reset-time macro state: everyone in standby and active (the joint first decision at t = 0)."""
    for b in range(worlds.shape[0]):
        if not worlds[b]:
            continue
        tr, tc = target[b, 0], target[b, 1]
        for i in range(mstate.shape[1]):
            for f in range(M_FIELDS):
                mstate[b, i, f] = 0
            mstate[b, i, M_STANDBY] = 1
            mstate[b, i, M_ACTIVE] = 1
            mstate[b, i, M_KNEW] = 1 if belief[b, i, tr, tc] & TARGET_BIT else 0


@njit(cache=True, nogil=True)  # threads=: chunks of worlds run at once
def assign_goals(
    worlds: np.ndarray,
    goal_cells: np.ndarray,  # (B, N, 2) int64 new goals (read for active robots only)
    goal: np.ndarray,
    mstate: np.ndarray,
    ma_rewards: np.ndarray,
    comp: np.ndarray,  # (B, N) the neighbourhoods the robots decided in
    heard_goal: np.ndarray,  # (B, N, N, 2) out: a neighbour's news of a robot holds its new goal
) -> None:
    """Start the macro-actions of the active robots of the given worlds. A neighbourhood decides together,
    so its members' news of a robot that decides (``heard_goal``) holds the goal it chose."""
    n = goal.shape[1]
    for b in range(worlds.shape[0]):
        if not worlds[b]:
            continue
        for i in range(n):
            if mstate[b, i, M_ACTIVE]:
                goal[b, i, 0] = goal_cells[b, i, 0]
                goal[b, i, 1] = goal_cells[b, i, 1]
                for k in range(n):
                    if comp[b, k] == comp[b, i]:
                        heard_goal[b, k, i, 0] = goal_cells[b, i, 0]
                        heard_goal[b, k, i, 1] = goal_cells[b, i, 1]
                mstate[b, i, M_ACTIVE] = 0
                mstate[b, i, M_STANDBY] = 0
                mstate[b, i, M_MA_TICKS] = 0
                mstate[b, i, M_WAIT] = 0
                mstate[b, i, M_ELAPSED] = 0
                ma_rewards[b, i] = 0.0
