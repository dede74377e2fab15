"""Functions the job runner's tests map over items in worker processes (local pool, Ray tasks): they
must be importable there, so they live in a module of their own."""

from __future__ import annotations

import os
import time
from pathlib import Path


def square(x: int) -> int:
    return x * x


def dies_once(item: tuple[int, str]) -> int:
    """The item squared; the first call for it (no marker file yet) ends its process as a lost worker
    would (os._exit, no exception)."""
    x, folder = item
    marker = Path(folder) / f"died-{x}"
    if not marker.exists():
        marker.write_text(str(os.getpid()))
        os._exit(1)
    return x * x


def sleeps(seconds: float) -> float:
    time.sleep(seconds)
    return seconds


def fails(x: int) -> int:
    raise ValueError(f"bad item {x}")
