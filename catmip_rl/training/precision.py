"""Precision of the PPO update on CPU: float32, or bfloat16 autocast where the CPU has it natively.

On CPUs with native bf16 instructions (AVX-512 BF16, AMX) a training step under bf16 autocast measured
1.6x the float32 throughput; on AVX2-only CPUs torch emulates bf16 and the same step ran 14x slower
(docs/benchmarks.md). Native bf16 is not enough either: a Task-1 update (d = 64) stopped early by the KL
target, on minibatches of a few hundred events, ran only ~4 % faster in bf16. ``precision="auto"``
therefore measures both on the run's first batch where the CPU reports native bf16, and takes bf16 only
if it is at least 10 % faster. Parameters, optimiser state, losses and the sparse global convolution
stay float32 either way.
"""

from __future__ import annotations

import platform
import time
from functools import cache

import torch

__all__ = ["PRECISIONS", "native_bf16", "use_bf16", "measure_bf16", "choose_bf16"]

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


def measure_bf16(model, batch, loss_kwargs: dict, events: int = 512, repeats: int = 2) -> dict[str, float]:
    """Seconds of one forward + backward of the PPO loss on the first ``events`` events of ``batch``,
    float32 and bf16 autocast (best of ``repeats`` after a warm-up each); the model's gradients are
    left cleared."""
    from catmip_rl.training.ppo import accumulate_gradients

    part = torch.arange(min(events, len(batch)), device=batch.action.device)
    count = batch.trainable[part].sum().clamp_min(1).float()
    out = {}
    for name, bf16 in (("fp32_s", False), ("bf16_s", True)):
        best = float("inf")
        for k in range(repeats + 1):
            model.zero_grad(set_to_none=True)
            t0 = time.perf_counter()
            accumulate_gradients(model, batch, [part], count, **(loss_kwargs | {"bf16": bf16}))
            if k:  # the first run warms up (oneDNN primitives, allocator)
                best = min(best, time.perf_counter() - t0)
        out[name] = best
    model.zero_grad(set_to_none=True)
    return out


def choose_bf16(precision: str, device: str, model, batch, loss_kwargs: dict, events: int = 512):
    """(bf16 or not, what decided it): "auto" on a CPU with native bf16 measures both on this batch
    and takes bf16 only if it is at least 10 % faster; everything else as :func:`use_bf16`."""
    if precision != "auto" or not device.startswith("cpu") or not native_bf16():
        return use_bf16(precision, device), {"precision": precision, "native_bf16": native_bf16()}
    timing = measure_bf16(model, batch, loss_kwargs, events)
    bf16 = timing["bf16_s"] < 0.9 * timing["fp32_s"]
    return bf16, {"precision": precision, "native_bf16": True, **timing, "bf16": bf16}
