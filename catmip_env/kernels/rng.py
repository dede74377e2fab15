"""Per-world random streams for the numba kernels.

Each world owns one 64-bit SplitMix64 state (``rng: (B,) uint64``), seeded from the episode's
``numpy.random.SeedSequence``; kernels draw from ``rng[b]`` only, so a world's trajectory depends on its
own seed, episode index and actions, never on the batch it runs in.
"""

from __future__ import annotations

import numpy as np
from numba import njit, uint64

_GOLDEN = uint64(0x9E3779B97F4A7C15)
_M1 = uint64(0xBF58476D1CE4E5B9)
_M2 = uint64(0x94D049BB133111EB)
_INV_2_53 = 1.0 / 9007199254740992.0


@njit(cache=True, inline="always")
def next_u64(rng: np.ndarray, b: int) -> np.uint64:
    s = rng[b] + _GOLDEN
    rng[b] = s
    z = s
    z = (z ^ (z >> uint64(30))) * _M1
    z = (z ^ (z >> uint64(27))) * _M2
    return z ^ (z >> uint64(31))


@njit(cache=True, inline="always")
def uniform(rng: np.ndarray, b: int) -> float:
    """A float in [0, 1)."""
    return float(next_u64(rng, b) >> uint64(11)) * _INV_2_53


@njit(cache=True, inline="always")
def randint(rng: np.ndarray, b: int, n: int) -> int:
    """An int in [0, n)."""
    return min(int(uniform(rng, b) * n), n - 1)


def seed_state(seq: np.random.SeedSequence) -> np.uint64:
    """The 64-bit kernel state derived from a seed sequence."""
    return np.uint64(seq.generate_state(1, dtype=np.uint64)[0])
