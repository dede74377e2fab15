"""Keep freed memory in the process heap during training (Linux, glibc).

A PPO step allocates and frees activations of 5-20 MB each (the local CNN's feature maps, the embedder's
inputs). glibc's malloc serves blocks that large with fresh ``mmap`` pages, or trims them off the top
of the heap once freed, so every step page-faults its working set in again: ~4,000-8,000 faults a step on a
Task-2 batch, 5-10 % of the step on the 2-core VM this project is measured on. Raising the mmap and trim
thresholds makes malloc serve them from the heap and keep what is freed, so later steps reuse the pages
(~100 faults a step). The cost is memory the process keeps after its peak, which training reaches again
every step anyway.

``keep_freed_memory()`` is called by ``catmip_rl.training.train.train`` and the training benchmarks; set
``CATMIP_KEEP_HEAP=0`` to leave malloc as it is. Elsewhere (macOS, musl, Windows) it does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys

__all__ = ["keep_freed_memory", "MMAP_THRESHOLD", "TRIM_THRESHOLD"]

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 32 << 20
"""Blocks up to this size come from the heap (glibc's upper limit for it on 64-bit systems)."""
TRIM_THRESHOLD = 1 << 30
"""Free memory at the top of the heap is returned to the system only beyond this much."""

_done: bool | None = None


def keep_freed_memory() -> bool:
    """Set glibc's mmap and trim thresholds once per process; True if they are set."""
    global _done
    if _done is None:
        _done = False
        if sys.platform.startswith("linux") and os.environ.get("CATMIP_KEEP_HEAP", "1") != "0":
            try:
                mallopt = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").mallopt
            except (OSError, AttributeError):  # not glibc
                return False
            mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
            mmap_set = bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD))
            _done = mmap_set and bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD))
    return _done
