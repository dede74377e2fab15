"""Precision of the PPO update on CPU: float32, or bfloat16 autocast where the CPU has it natively.

On CPUs with native bf16 instructions (AVX-512 BF16, AMX) a training step under bf16 autocast measured
1.6x the float32 throughput; on AVX2-only CPUs torch emulates bf16 and the same step ran 14x slower
(docs/benchmarks.md). Native bf16 is not enough either: a Task-1 update (d = 64) stopped early by the KL
target, on minibatches of a few hundred events, ran only ~4 % faster in bf16. ``precision="auto"``
therefore measures both on the run's first batch where the CPU reports native bf16, and takes bf16 only
if it is at least 10 % faster (``ppo.choose_bf16``: the measurement is a PPO step). Parameters,
optimiser state, losses and the sparse global convolution stay float32 either way.
"""

from __future__ import annotations

import platform
from functools import cache

__all__ = ["PRECISIONS", "native_bf16", "use_bf16"]

PRECISIONS = ("fp32", "bf16", "auto")
_NATIVE_FLAGS = ("avx512_bf16", "amx_bf16")


@cache
def native_bf16() -> bool:
    """Whether this CPU executes bf16 natively (Linux: an ``avx512_bf16`` or ``amx_bf16`` flag in
    /proc/cpuinfo; elsewhere False)."""
    if platform.system() != "Linux":
        return False
    try:
        with open("/proc/cpuinfo") as f:
            flags = next((line for line in f if line.startswith("flags")), "")
    except OSError:
        return False
    return any(flag in flags.split() for flag in _NATIVE_FLAGS)


def use_bf16(precision: str, device: str) -> bool:
    """Resolve a ``TrainConfig.precision`` for ``device``: bf16 autocast on CPU or not."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {list(PRECISIONS)}, got {precision!r}")
    if not device.startswith("cpu"):
        return precision == "bf16"
    return precision == "bf16" or (precision == "auto" and native_bf16())
