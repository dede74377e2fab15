"""Communication inside one world: neighbourhoods, belief merging, and what robots remember of each other.

Every tick (docs/design.md#communication-and-slam-noise): :func:`draw_neighbourhoods` links robots,
:func:`merge_beliefs` OR-merges the maps inside each neighbourhood, and :func:`remember` updates each
robot's memory of its teammates — where and when it last had news of each, whether that teammate
knew the target then and the goal it was heading for (:func:`estimated_cells`: where it should be now).
News travels as maps do: a neighbourhood shares its members' memories, the freshest news of each
teammate winning. The memory draws no random numbers; it is shown in the observation only with
``EnvConfig.teammate_memory`` (planners may read it from the state).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from catmip_env.constants import TARGET_BIT
from catmip_env.kernels.rng import uniform

__all__ = ["draw_neighbourhoods", "merge_beliefs", "remember", "estimated_cells"]


@njit(cache=True)
def _find(parent: np.ndarray, i: int) -> int:
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit(cache=True)
def draw_neighbourhoods(
    b: int, pos: np.ndarray, comm_sigma: float, rng: np.ndarray, comp: np.ndarray
) -> None:
    """Label each robot with its neighbourhood (the lowest robot id of its component).

    ``comm_sigma <= 0`` means full communication. Otherwise pair (i, j) is linked with probability
    exp(-d^2 / sigma^2); one uniform draw per pair, pairs in (i, j) lexicographic order.
    """
    n = pos.shape[1]
    if comm_sigma <= 0.0:
        for i in range(n):
            comp[b, i] = 0
        return
    parent = np.arange(n)
    inv_s2 = 1.0 / (comm_sigma * comm_sigma)
    for i in range(n):
        for j in range(i + 1, n):
            dr = pos[b, i, 0] - pos[b, j, 0]
            dc = pos[b, i, 1] - pos[b, j, 1]
            p = math.exp(-(dr * dr + dc * dc) * inv_s2)
            if uniform(rng, b) < p:
                ri, rj = _find(parent, i), _find(parent, j)
                if ri != rj:
                    parent[max(ri, rj)] = min(ri, rj)
    for i in range(n):
        comp[b, i] = _find(parent, i)


@njit(cache=True)
def merge_beliefs(b: int, comp: np.ndarray, belief: np.ndarray) -> None:
    """OR-merge the beliefs of every neighbourhood and write the result back to each member.

    The first member's map accumulates the OR (flat, vectorisable loops), then is copied to the rest.
    """
    n = belief.shape[1]
    hw = belief.shape[2] * belief.shape[3]
    for root in range(n):
        if comp[b, root] != root:
            continue  # labels are the lowest member id, so every component is visited once
        acc = belief[b, root].reshape(hw)
        members = 1
        for i in range(root + 1, n):
            if comp[b, i] == root:
                src = belief[b, i].reshape(hw)
                for k in range(hw):
                    acc[k] |= src[k]
                members += 1
        if members < 2:
            continue
        for i in range(root + 1, n):
            if comp[b, i] == root:
                dst = belief[b, i].reshape(hw)
                for k in range(hw):
                    dst[k] = acc[k]


@njit(cache=True)
def remember(
    b: int,
    tick: int,
    pos: np.ndarray,  # (B, N, 2)
    comp: np.ndarray,  # (B, N) neighbourhood labels of this tick
    belief: np.ndarray,  # (B, N, H, W) merged beliefs of this tick
    target: np.ndarray,  # (B, 2)
    heard_tick: np.ndarray,  # (B, N, N) int64 out: tick of i's latest news of j, -1 = none
    heard_pos: np.ndarray,  # (B, N, N, 2) int64 out: where j was then
    heard_knows: np.ndarray,  # (B, N, N) bool out: whether j knew the target then
    goal: np.ndarray,  # (B, N, 2) the robots' current goals, -1 = none
    heard_goal: np.ndarray,  # (B, N, N, 2) int64 out: the goal j was heading for then
) -> None:
    """Robot i's news of teammate j after this tick's merge: first-hand for the members of i's
    neighbourhood, otherwise the freshest news any member of it holds."""
    n = pos.shape[1]
    tr, tc = target[b, 0], target[b, 1]
    for j in range(n):
        knows = (belief[b, j, tr, tc] & TARGET_BIT) != 0
        for i in range(n):
            if comp[b, i] == comp[b, j]:
                heard_tick[b, i, j] = tick
                heard_pos[b, i, j, 0] = pos[b, j, 0]
                heard_pos[b, i, j, 1] = pos[b, j, 1]
                heard_knows[b, i, j] = knows
                heard_goal[b, i, j, 0] = goal[b, j, 0]
                heard_goal[b, i, j, 1] = goal[b, j, 1]
    for root in range(n):
        if comp[b, root] != root:
            continue
        for j in range(n):
            if comp[b, j] == root:
                continue  # first-hand news, written above
            best = root
            for k in range(root + 1, n):
                if comp[b, k] == root and heard_tick[b, k, j] > heard_tick[b, best, j]:
                    best = k
            for k in range(root, n):
                if comp[b, k] == root and k != best:
                    heard_tick[b, k, j] = heard_tick[b, best, j]
                    heard_pos[b, k, j, 0] = heard_pos[b, best, j, 0]
                    heard_pos[b, k, j, 1] = heard_pos[b, best, j, 1]
                    heard_knows[b, k, j] = heard_knows[b, best, j]
                    heard_goal[b, k, j, 0] = heard_goal[b, best, j, 0]
                    heard_goal[b, k, j, 1] = heard_goal[b, best, j, 1]


def estimated_cells(
    heard_tick: np.ndarray,  # (..., N, N) int64, -1 = no news
    heard_pos: np.ndarray,  # (..., N, N, 2)
    heard_goal: np.ndarray,  # (..., N, N, 2), -1 = no goal
    ticks: np.ndarray,  # (...) int64: each world's tick now
    speed: np.ndarray,  # (..., N) int64: each teammate's ticks per cell
) -> np.ndarray:
    """(..., N, N, 2) int64: where robot i estimates teammate j to be now, from its latest news of j: the
    cell j was at, moved toward the goal j was heading for, in a straight line at j's speed for the ticks
    since, stopping at the goal (the cell itself without a goal or without news)."""
    pos = heard_pos.astype(np.float64)
    ahead = heard_goal.astype(np.float64) - pos
    span = np.hypot(ahead[..., 0], ahead[..., 1])
    elapsed = np.maximum(np.asarray(ticks)[..., None, None] - heard_tick, 0)
    travelled = elapsed / speed[..., None, :]
    moving = (heard_tick >= 0) & (heard_goal[..., 0] >= 0) & (span > 0)
    frac = np.where(moving, np.minimum(1.0, travelled / np.maximum(span, 1e-9)), 0.0)
    return np.rint(pos + ahead * frac[..., None]).astype(np.int64)
