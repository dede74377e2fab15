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


def split_payload(item: tuple[int, bytes]) -> tuple[int, bytes]:
    return item


def join_payload(x: int, payload: bytes) -> tuple[int, int]:
    return x, len(payload)


def sized(item: tuple[int, int]) -> int:
    """The item's number times its payload's size (what a task with a shared payload sees)."""
    x, size = item
    return x * size
