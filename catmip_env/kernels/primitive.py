"""One primitive step of a small batch in one kernel call: the actions checked, the tick, the observations.

A step of one world (the PettingZoo env at the primitive level, or a batch too small to split over
threads) is a few microseconds of work, and calling a numba kernel costs about that much again: numba
works out the types of its arguments at every call (about 5 us for the world state, a namedtuple of 26
arrays). :func:`tick_and_observe` does the tick and the observations in one call, and
:class:`DirectCall` calls it at its compiled entry for the argument types of its first call, without
that per-call type dispatch (``Dispatcher.compile`` returns the entry; about 1.4 us a call).
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
from numba import njit

from catmip_env.constants import TARGET_BIT
from catmip_env.kernels.dynamics import Rules, tick
from catmip_env.kernels.observe import observe
from catmip_env.kernels.state import KernelState

__all__ = ["DirectCall", "robot_view", "tick_and_observe", "tick_observe_view"]


@njit(cache=True, nogil=True)
def tick_and_observe(
    live: np.ndarray,  # (B,) bool: worlds to advance (those not done)
    actions: np.ndarray,  # (B, N) int64 primitive actions, C-contiguous
    s: KernelState,
    rules: Rules,
    rewards: np.ndarray,  # (B, N) float64 out
    terminated: np.ndarray,  # (B,) bool out
    truncated: np.ndarray,  # (B,) bool out
    noisy: bool,
    memory: bool,
    obs_global: np.ndarray,  # (B, N, 5 + C, H, W) uint8 out
    obs_local: np.ndarray,  # (B, N, 4 + C, L, L) uint8 out
) -> int:
    """:func:`~.dynamics.tick` then :func:`~.observe.observe` of the live worlds, teammates drawn where
    they were last heard of (no heading estimate). Returns -1, or ``b * N + i`` of the first action
    outside [0, 4) — and then nothing has changed."""
    n = actions.shape[1]
    for b in range(actions.shape[0]):
        for i in range(n):
            if actions[b, i] < 0 or actions[b, i] > 3:
                return b * n + i
    tick(live, actions, s, rules, rewards, terminated, truncated)
    observe(
        live,
        s.belief,
        s.used_occ,
        noisy,
        s.pos,
        s.cls,
        s.comp,
        s.goal,
        s.target,
        obs_global,
        obs_local,
        memory,
        s.heard_tick,
        s.heard_pos,
        s.heard_knows,
    )
    return -1


class DirectCall:
    """A numba kernel called at its compiled entry point for the argument types of its first call.

    The caller holds the types fixed: the same arrays (or arrays of the same dtype, dimensions and
    C layout) and the same namedtuple types at every call. The entry unboxes what it is given as those
    types without checking them, so an argument of another layout would be read wrongly: pass only
    arrays the caller made.
    """

    def __init__(self, kernel: Any) -> None:
        self.kernel = kernel
        self.entry: Any = None  # the compiled entry, once called: a caller in a hot loop may call it itself

    def __getstate__(self) -> dict[str, Any]:
        return {"kernel": self.kernel, "entry": None}  # the entry is this process's: found again when called

    def __call__(self, *args: Any) -> Any:
        if self.entry is None:
            self.entry = self.kernel.compile(tuple(numba.typeof(a) for a in args))
        return self.entry(*args)


@njit(cache=True, nogil=True)
def robot_view(
    b: int,  # the world
    obs_global: np.ndarray,  # (B, N, 5 + C, H, W) uint8
    obs_local: np.ndarray,  # (B, N, 4 + C, L, L) uint8
    s: KernelState,
    scale: float,  # OBS_SCALE
    global_out: np.ndarray,  # (N, 5 + C, H, W) float32 out
    local_out: np.ndarray,  # (N, 4 + C, L, L) float32 out
    class_out: np.ndarray,  # (N, C) float32 out: class one-hot
    heading_out: np.ndarray,  # (N, 4) float32 out: heading one-hot
    info_out: np.ndarray,  # (N, 5) int64 out: class, neighbourhood, can act now, knows the target, tick
) -> None:
    """What the primitive-level env gives of world ``b``, written into new arrays in one call: each
    robot's maps as float32 ``value * scale``, its class and heading one-hot, and its info numbers."""
    g, l = obs_global[b].ravel(), obs_local[b].ravel()
    gf, lf = global_out.ravel(), local_out.ravel()
    s32 = np.float32(scale)  # float32 products (exact: a uint8 times 0.25), a vectorised loop
    for k in range(g.size):
        gf[k] = np.float32(g[k]) * s32
    for k in range(l.size):
        lf[k] = np.float32(l[k]) * s32
    class_out[:] = 0.0
    heading_out[:] = 0.0
    t, tr, tc = s.ticks[b], s.target[b, 0], s.target[b, 1]
    for i in range(class_out.shape[0]):
        class_out[i, s.cls[b, i]] = 1.0
        heading_out[i, s.heading[b, i]] = 1.0
        info_out[i, 0] = s.cls[b, i]
        info_out[i, 1] = s.comp[b, i]
        info_out[i, 2] = 1 if t % s.speed[b, i] == 0 else 0
        info_out[i, 3] = 1 if s.belief[b, i, tr, tc] & TARGET_BIT else 0
        info_out[i, 4] = t


@njit(cache=True, nogil=True)
def tick_observe_view(
    s: KernelState,
    rules: Rules,
    rewards: np.ndarray,  # (B, N) float64 out
    terminated: np.ndarray,  # (B,) bool out
    truncated: np.ndarray,  # (B,) bool out
    noisy: bool,
    memory: bool,
    obs_global: np.ndarray,  # (B, N, 5 + C, H, W) uint8 out
    obs_local: np.ndarray,  # (B, N, 4 + C, L, L) uint8 out
    scale: float,  # OBS_SCALE
    b: int,  # the world whose view is written
    actions: np.ndarray,  # (B, N) int64 primitive actions, C-contiguous
    global_out: np.ndarray,  # the rest as robot_view's
    local_out: np.ndarray,
    class_out: np.ndarray,
    heading_out: np.ndarray,
    info_out: np.ndarray,
) -> int:
    """:func:`tick_and_observe` of the worlds not done, then :func:`robot_view` of world ``b``; -1, or
    the first out-of-range action's ``b * N + i`` (nothing changed, no view written)."""
    live = ~s.done
    bad = tick_and_observe(
        live, actions, s, rules, rewards, terminated, truncated, noisy, memory, obs_global, obs_local
    )
    if bad < 0:
        robot_view(
            b, obs_global, obs_local, s, scale, global_out, local_out, class_out, heading_out, info_out
        )
    return bad
