"""World state: the struct of arrays of B worlds, and the same arrays as one value for the numba kernels.

* :class:`WorldState` — the engine's state (``BatchedWorld.state``): one dataclass of arrays, B worlds
  of N robots on H x W maps. Its fields are allocated once and never rebound (the dataclass is frozen):
  code changes the state by writing *into* the arrays.
* :class:`KernelState` — the same arrays as one ``typing.NamedTuple`` (``WorldState.kernel``), which
  the entry kernels (:func:`~.dynamics.tick`, :func:`~.macro.advance`) take as one
  argument. numba compiles namedtuple arguments like any other and caches them on disk; a ``jitclass``
  is passed a few microseconds faster per call but compiled again in every process (2-3 s per start).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from functools import cached_property
from typing import NamedTuple

import numpy as np

__all__ = ["WorldState", "KernelState"]


@dataclass(frozen=True)
class WorldState:
    """Struct-of-arrays state of B worlds with N robots on H x W maps (C classes)."""

    grid: np.ndarray  # (B, H, W) uint8 ground-truth cell codes (constants.FREE ... constants.CLUE)
    target: np.ndarray  # (B, 2) int64 target cell
    pos: np.ndarray  # (B, N, 2) int64 robot cells
    heading: np.ndarray  # (B, N) int64 0=E 1=S 2=W 3=N
    cls: np.ndarray  # (B, N) int64 class index
    speed: np.ndarray  # (B, N) int64 ticks per primitive action
    can_rescue: np.ndarray  # (B, N) bool
    belief: np.ndarray  # (B, N, H, W) uint8 belief bits (constants.EXPLORED | OCCUPIED | ...)
    used_occ: np.ndarray  # (B, N, H, W) uint8 noisy occupancy used this tick (noise only)
    comp: np.ndarray  # (B, N) int64 neighbourhood label = lowest robot id of the component
    goal: np.ndarray  # (B, N, 2) int64 current goal cell, -1 = none (macro level)
    rng: np.ndarray  # (B,) uint64 per-world dynamics stream
    ticks: np.ndarray  # (B,) int64 ticks elapsed in the episode
    moves: np.ndarray  # (B, N) int64 successful forward moves in the episode
    collisions: np.ndarray  # (B, N) int64 forward moves that hit a wall, obstacle or the target
    found_tick: np.ndarray  # (B,) int64 tick the target first became known, -1 = not yet
    informed_tick: np.ndarray  # (B,) int64 tick a robot that can rescue first knew the target, -1 = not yet
    rescue_tick: np.ndarray  # (B,) int64 tick of success, -1 = not yet
    done: np.ndarray  # (B,) bool episode over (terminated or truncated)
    episode: np.ndarray  # (B,) int64 episode index of each world's current episode
    pending_reward: np.ndarray  # (B, N) float64 rewards earned at reset, paid with the next step
    comm_sigma: np.ndarray  # (B,) float64 communication range of the episode, 0 = full communication
    heard_tick: np.ndarray  # (B, N, N) int64 tick of i's latest news of j, -1 = none (comms)
    heard_pos: np.ndarray  # (B, N, N, 2) int64 where robot j was then
    heard_knows: np.ndarray  # (B, N, N) bool whether robot j knew the target then
    heard_goal: np.ndarray  # (B, N, N, 2) int64 the goal robot j was heading for then, -1 = none

    @classmethod
    def allocate(cls, num_worlds: int, num_robots: int, shape: tuple[int, int], noisy: bool) -> WorldState:
        """Zeroed state (every world ``done``, no episode yet); ``used_occ`` is a dummy without noise."""
        b, n, (h, w) = num_worlds, num_robots, shape
        occ_shape = (b, n, h, w) if noisy else (1, 1, 1, 1)
        return cls(
            grid=np.zeros((b, h, w), np.uint8),
            target=np.zeros((b, 2), np.int64),
            pos=np.zeros((b, n, 2), np.int64),
            heading=np.zeros((b, n), np.int64),
            cls=np.zeros((b, n), np.int64),
            speed=np.ones((b, n), np.int64),
            can_rescue=np.zeros((b, n), np.bool_),
            belief=np.zeros((b, n, h, w), np.uint8),
            used_occ=np.zeros(occ_shape, np.uint8),
            comp=np.zeros((b, n), np.int64),
            goal=np.full((b, n, 2), -1, np.int64),
            rng=np.zeros(b, np.uint64),
            ticks=np.zeros(b, np.int64),
            moves=np.zeros((b, n), np.int64),
            collisions=np.zeros((b, n), np.int64),
            found_tick=np.full(b, -1, np.int64),
            informed_tick=np.full(b, -1, np.int64),
            rescue_tick=np.full(b, -1, np.int64),
            done=np.ones(b, np.bool_),
            episode=np.full(b, -1, np.int64),
            pending_reward=np.zeros((b, n), np.float64),
            comm_sigma=np.zeros(b, np.float64),
            heard_tick=np.full((b, n, n), -1, np.int64),
            heard_pos=np.zeros((b, n, n, 2), np.int64),
            heard_knows=np.zeros((b, n, n), np.bool_),
            heard_goal=np.full((b, n, n, 2), -1, np.int64),
        )

    def __getstate__(self) -> dict:
        # the kernel values and chunks are views: a pickled view comes back a copy of its own
        return {k: v for k, v in self.__dict__.items() if k not in ("kernel", "_chunks")}

    def copy(self) -> WorldState:
        """A deep copy (new arrays)."""
        return WorldState(**{f.name: getattr(self, f.name).copy() for f in fields(self)})

    @cached_property
    def kernel(self) -> KernelState:
        """The same arrays (not copies) as one :class:`KernelState` value, built on first use."""
        return KernelState(*(getattr(self, f.name) for f in fields(self)))

    def kernel_chunk(self, worlds: slice) -> KernelState:
        """:attr:`kernel` of the worlds in ``worlds`` only (views: writes reach this state), for a thread
        that steps a chunk of the worlds; ``used_occ``'s one-cell placeholder (no SLAM noise) is shared.
        Built once per chunk (the arrays are never rebound); the whole range is :attr:`kernel` itself."""
        key = (worlds.start, worlds.stop)
        chunk = self._chunks.get(key)
        if chunk is None:
            b = self.grid.shape[0]
            whole = range(b)[worlds] == range(b)
            chunk = (
                self.kernel
                if whole
                else KernelState(*(a if a.shape[0] != b else a[worlds] for a in self.kernel))
            )
            self._chunks[key] = chunk
        return chunk

    @cached_property
    def _chunks(self) -> dict[tuple, KernelState]:
        return {}


#: The fields of :class:`WorldState`, same names, order and arrays, as one immutable value that numba
#: kernels take as a single argument (field access ``s.grid``; heterogeneous namedtuples are supported).
KernelState = NamedTuple("KernelState", [(f.name, np.ndarray) for f in fields(WorldState)])
