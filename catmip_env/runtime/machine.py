"""The machine a result was measured on: every benchmark and suite entry records it (CPUs differ between
sessions: AVX2-only, or AVX-512 with native bf16)."""

from __future__ import annotations

import platform
from typing import Any

__all__ = ["cpu_flags", "machine_info"]


def cpu_flags() -> set[str]:
    """The CPU's feature flags (Linux /proc/cpuinfo), empty elsewhere."""
    try:
        with open("/proc/cpuinfo") as f:
            line = next((line for line in f if line.startswith("flags")), "")
    except OSError:
        return set()
    return set(line.partition(":")[2].split())


def machine_info(**extra: Any) -> dict[str, Any]:
    """What every benchmark records beside its numbers: Python, CPU, its vector capability (AVX512 /
    AVX2 / DEFAULT from the CPU flags: torch's names for what it dispatches to) and whether it has native
    bf16; ``extra`` is merged in."""
    flags = cpu_flags()
    capability = "AVX512" if "avx512f" in flags else "AVX2" if "avx2" in flags else "DEFAULT"
    return {
        "python": platform.python_version(),
        "cpu": platform.processor() or platform.machine(),
        "cpu_capability": capability,
        "native_bf16": bool(flags & {"avx512_bf16", "amx_bf16"}),
        **extra,
    }
