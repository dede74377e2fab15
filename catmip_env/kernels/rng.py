"""Per-world random streams for the numba kernels.

Each world owns one 64-bit SplitMix64 state (``rng: (B,) uint64``), seeded from the episode's
``numpy.random.SeedSequence``; kernels draw from ``rng[b]`` only, so a world's trajectory depends on its
own seed, episode index and actions, never on the batch it runs in.

Map generation draws from a block of numpy uniforms instead (the episode's map stream): ``block_*``
consume it in order through a cursor ``p`` (one int64).
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


@njit(cache=True, inline="always")
def block_uniform(u: np.ndarray, p: np.ndarray) -> float:
    """Next uniform of the block ``u`` at the cursor ``p[0]`` (advanced; 0.5 once exhausted: the caller
    sees ``p[0] > len(u)`` and retries with a bigger block)."""
    k = p[0]
    p[0] = k + 1
    return u[k] if k < u.shape[0] else 0.5


@njit(cache=True, inline="always")
def block_randint(u: np.ndarray, p: np.ndarray, n: int) -> int:
    """Uniform int in [0, n) from the block."""
    return min(int(block_uniform(u, p) * n), n - 1)


@njit(cache=True)
def block_choose(cells: np.ndarray, count: int, k: int, u: np.ndarray, p: np.ndarray) -> None:
    """Move a uniform k-subset of cells[:count] to the front (partial Fisher-Yates)."""
    for j in range(k):
        m = j + block_randint(u, p, count - j)
        cells[j], cells[m] = cells[m], cells[j]
