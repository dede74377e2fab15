"""An episode's random streams drawn inside a kernel, bit for bit as numpy draws them.

Every episode's streams come from ``numpy.random.SeedSequence(seed, spawn_key=(episode, k))``: the map
stream (k = 0, a ``numpy.random.Generator`` on PCG64), the dynamics state (k = 1) and the world key
(k = 2). Building them in Python costs about 60 us a world (three seed sequences and a Generator), under
the GIL; a reset of many worlds was one thread's Python. The functions here compute the same seed
sequence hash (numpy's ``SeedSequence``: pool of 4 words, ``mix_entropy``, ``generate_state``), the
same PCG64 (128-bit LCG, XSL-RR output) and the same ``Generator.random`` and small
``Generator.integers`` (Lemire's method on the buffered 32-bit half), so that a reset runs in a
``nogil`` kernel, on every thread, and draws exactly the maps the Python streams draw
(``tests/env/test_seeding.py`` checks them against numpy).

A PCG64 stream is a (6,) uint64 array: state high and low words, increment high and low words, whether
a 32-bit half is buffered, the buffered half.
"""

from __future__ import annotations

import numpy as np
from numba import njit, uint64

__all__ = [
    "int_words",
    "pcg64_integer",
    "pcg64_stream",
    "pcg64_uniforms",
    "seed_words",
]

_M32 = uint64(0xFFFFFFFF)
_S16, _S32, _S11, _S58, _S64M = uint64(16), uint64(32), uint64(11), uint64(58), uint64(63)
_INIT_A, _MULT_A = uint64(0x43B0D7E5), uint64(0x931E8875)
_INIT_B, _MULT_B = uint64(0x8B51F9DD), uint64(0x58F38DED)
_MIX_L, _MIX_R = uint64(0xCA01F9DD), uint64(0x4973F715)
_PCG_MULT_HI, _PCG_MULT_LO = uint64(2549297995355413924), uint64(4865540595714422341)
_ONE, _ZERO = uint64(1), uint64(0)
_INV_2_53 = 1.0 / 9007199254740992.0
POOL = 4  # numpy's default pool size


@njit(cache=True, nogil=True, inline="always")
def _hashmix(value: np.uint64, hc: np.ndarray) -> np.uint64:
    value = value ^ hc[0]
    hc[0] = (hc[0] * _MULT_A) & _M32
    value = (value * hc[0]) & _M32
    return value ^ (value >> _S16)


@njit(cache=True, nogil=True, inline="always")
def _mix(x: np.uint64, y: np.uint64) -> np.uint64:
    r = (_MIX_L * x - _MIX_R * y) & _M32
    return r ^ (r >> _S16)


def int_words(x: int) -> np.ndarray:
    """The 32-bit words of a non-negative int, low first (0 is one word), as numpy's seed sequence takes
    an int's entropy: (K,) uint64."""
    words = [x & 0xFFFFFFFF]
    x >>= 32
    while x > 0:
        words.append(x & 0xFFFFFFFF)
        x >>= 32
    return np.array(words, np.uint64)


@njit(cache=True, nogil=True, inline="always")
def _episode_words(x: int, out: np.ndarray, k: int) -> int:
    """:func:`int_words` of an int64 >= 0 written from ``out[k]``; the next free index."""
    v = uint64(x)
    out[k] = v & _M32
    k += 1
    v >>= _S32
    while v > _ZERO:
        out[k] = v & _M32
        k += 1
        v >>= _S32
    return k


@njit(cache=True, nogil=True)
def seed_words(seed: np.ndarray, episode: int, child: int, n64: int) -> np.ndarray:
    """``SeedSequence(s, spawn_key=(episode, child)).generate_state(n64, np.uint64)``, ``seed`` being
    :func:`int_words` of ``s`` (any int >= 0)."""
    k = seed.shape[0]
    entropy = np.zeros(max(k, POOL) + 3, np.uint64)  # the run entropy padded to the pool, the spawn key
    entropy[:k] = seed
    k = _episode_words(episode, entropy, max(k, POOL))
    k = _episode_words(child, entropy, k)
    pool = np.zeros(POOL, np.uint64)
    hc = np.full(1, _INIT_A, np.uint64)
    for i in range(POOL):
        pool[i] = _hashmix(entropy[i] if i < k else _ZERO, hc)
    for i_src in range(POOL):
        for i_dst in range(POOL):
            if i_src != i_dst:
                pool[i_dst] = _mix(pool[i_dst], _hashmix(pool[i_src], hc))
    for i_src in range(POOL, k):
        for i_dst in range(POOL):
            pool[i_dst] = _mix(pool[i_dst], _hashmix(entropy[i_src], hc))
    out = np.zeros(n64, np.uint64)
    h = _INIT_B
    for i in range(2 * n64):
        v = pool[i % POOL] ^ h
        h = (h * _MULT_B) & _M32
        v = (v * h) & _M32
        v ^= v >> _S16
        out[i // 2] |= v << (_S32 * uint64(i % 2))
    return out


@njit(cache=True, nogil=True, inline="always")
def _mul64(x: np.uint64, y: np.uint64) -> tuple[np.uint64, np.uint64]:
    """The 128-bit product of two 64-bit words, (high, low)."""
    x0, x1, y0, y1 = x & _M32, x >> _S32, y & _M32, y >> _S32
    p00, p01, p10, p11 = x0 * y0, x0 * y1, x1 * y0, x1 * y1
    mid = p10 + (p00 >> _S32) + (p01 & _M32)
    return p11 + (mid >> _S32) + (p01 >> _S32), (mid << _S32) | (p00 & _M32)


@njit(cache=True, nogil=True, inline="always")
def _step(g: np.ndarray) -> None:
    """state = state * multiplier + increment (mod 2**128)."""
    hi, lo = _mul64(g[1], _PCG_MULT_LO)
    hi = hi + g[0] * _PCG_MULT_LO + g[1] * _PCG_MULT_HI
    lo2 = lo + g[3]
    g[0] = hi + g[2] + (_ONE if lo2 < lo else _ZERO)
    g[1] = lo2


@njit(cache=True, nogil=True)
def pcg64_stream(seed: np.ndarray, episode: int, child: int) -> np.ndarray:
    """``numpy.random.PCG64(SeedSequence(s, spawn_key=(episode, child)))`` as a (6,) stream (``seed``:
    :func:`int_words` of ``s``)."""
    w = seed_words(seed, episode, child, 4)
    g = np.zeros(6, np.uint64)
    g[2] = (w[2] << _ONE) | (w[3] >> _S64M)  # increment = (initseq << 1) | 1
    g[3] = (w[3] << _ONE) | _ONE
    _step(g)
    lo = g[1] + w[1]  # state += initstate
    g[0] = g[0] + w[0] + (_ONE if lo < g[1] else _ZERO)
    g[1] = lo
    _step(g)
    return g


@njit(cache=True, nogil=True, inline="always")
def _next64(g: np.ndarray) -> np.uint64:
    _step(g)
    x = g[0] ^ g[1]
    r = g[0] >> _S58
    return (x >> r) | (x << ((uint64(64) - r) & _S64M))


@njit(cache=True, nogil=True)
def pcg64_uniforms(g: np.ndarray, n: int) -> np.ndarray:
    """``Generator.random(n)``: n floats in [0, 1)."""
    u = np.empty(n)
    for i in range(n):
        u[i] = float(_next64(g) >> _S11) * _INV_2_53
    return u


@njit(cache=True, nogil=True, inline="always")
def _next32(g: np.ndarray) -> np.uint64:
    if g[4] != _ZERO:
        g[4] = _ZERO
        return g[5]
    v = _next64(g)
    g[4] = _ONE
    g[5] = v >> _S32
    return v & _M32


@njit(cache=True, nogil=True)
def pcg64_integer(g: np.ndarray, n: int) -> int:
    """``Generator.integers(n)`` for 1 <= n < 2**32: an int in [0, n) (none drawn when n == 1)."""
    if n == 1:
        return np.int64(0)
    excl = uint64(n)
    m = _next32(g) * excl
    left = m & _M32
    if left < excl:
        threshold = (_M32 - (excl - _ONE)) % excl
        while left < threshold:
            m = _next32(g) * excl
            left = m & _M32
    return np.int64(m >> _S32)
