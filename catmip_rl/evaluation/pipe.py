"""The sandbox's pipe between the parent and its worker (:mod:`~catmip_rl.evaluation.sandbox`,
:mod:`~catmip_rl.evaluation.workers`): one message is a head (the parent's pickled, the worker's JSON)
and a payload of raw array bytes, framed by their lengths; and what the parent makes of the worker's
replies, checked and never unpickled (an answer's array, ``episode_columns()``, the counts, the module
list).

Sending: one ``sendmsg`` of the frame, head and arrays (no copy into one buffer). Receiving: a buffer read
with as few system calls as the message takes. A socket with a timeout (Python's, or the kernel's:
:func:`wait_in_slices`) calls ``on_wait()`` each time it times out, where the parent checks its bounds
(:mod:`~catmip_rl.evaluation.bounds`); it may raise.
"""

from __future__ import annotations

import socket
import struct
import sys
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from catmip_rl.evaluation.user_policy import PolicyError

__all__ = [
    "ARRAY_KINDS",
    "FRAME",
    "send_frame",
    "wait_in_slices",
    "FrameReader",
    "split_payload",
    "answer_array",
    "columns_of",
    "counts_of",
    "modules_of",
]

ARRAY_KINDS = "biufc"  # what an answer's array may hold (never objects)
FRAME = struct.Struct("<II")  # a message: its head's and its payload's lengths, then the head, the payload
_MAX_ELEMENTS = 1 << 28


def _raw(part: Any) -> memoryview:
    if isinstance(part, np.ndarray):
        part = np.ascontiguousarray(part).reshape(-1).view(np.uint8)
    return memoryview(part).cast("B")


def send_frame(
    sock: socket.socket, head: bytes, parts: Sequence[Any] = (), on_wait: Callable[[], None] | None = None
) -> None:
    """Send one message: ``head`` and, as its payload, the raw bytes of ``parts`` (arrays, bytes), in one
    system call where the socket takes it all. ``on_wait()`` is called whenever a socket with a timeout
    (Python's, or the kernel's: :func:`wait_in_slices`) times out; it may raise."""
    views = [_raw(p) for p in parts]
    views = [memoryview(FRAME.pack(len(head), sum(v.nbytes for v in views))), memoryview(head), *views]
    while views:
        try:
            sent = sock.sendmsg(views)
        except (TimeoutError, BlockingIOError):  # a timeout (Python's or the kernel's)
            if on_wait is None:
                raise
            on_wait()
            continue
        while sent:
            if sent >= views[0].nbytes:
                sent -= views.pop(0).nbytes
            else:
                views[0], sent = views[0][sent:], 0
        while views and not views[0].nbytes:
            views.pop(0)


def wait_in_slices(sock: socket.socket, seconds: float) -> None:
    """Make ``sock``'s reads and writes give up after ``seconds`` (the caller then checks what it waits
    for and waits again): the kernel's timeouts on Linux (``SO_RCVTIMEO``: a read that waits is one
    system call), Python's elsewhere."""
    if sys.platform.startswith("linux"):
        tv = struct.pack("ll", int(seconds), int(seconds % 1 * 1e6))
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, tv)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDTIMEO, tv)
    else:
        sock.settimeout(seconds)


class FrameReader:
    """The receiving end of a socket: messages read with as few system calls as they take (one, for a
    message that arrived whole and fits the buffer), each part a new buffer of its own."""

    def __init__(self, sock: socket.socket, size: int = 1 << 16) -> None:
        self.sock, self.buf, self.start, self.end = sock, bytearray(size), 0, 0

    def _recv_into(self, view: memoryview, on_wait: Callable[[], None] | None) -> int:
        while True:
            try:
                k = self.sock.recv_into(view)
            except (TimeoutError, BlockingIOError):  # a timeout (Python's or the kernel's)
                if on_wait is None:
                    raise
                on_wait()
                continue
            if k == 0:
                raise EOFError("the other end closed the pipe")
            return k

    def read(self, n: int, on_wait: Callable[[], None] | None) -> bytearray:
        """The next ``n`` bytes."""
        if n <= len(self.buf):
            while self.end - self.start < n:
                if self.start and len(self.buf) - self.start < n:  # room for the rest: move to the front
                    have = self.end - self.start
                    self.buf[:have] = self.buf[self.start : self.end]
                    self.start, self.end = 0, have
                self.end += self._recv_into(memoryview(self.buf)[self.end :], on_wait)
            out = self.buf[self.start : self.start + n]
            self.start += n
            return out
        out = bytearray(n)  # longer than the buffer: what it holds, then straight into the message
        have = self.end - self.start
        out[:have] = self.buf[self.start : self.end]
        self.start = self.end = 0
        view = memoryview(out)
        while have < n:
            have += self._recv_into(view[have:], on_wait)
        return out

    def frame(
        self, on_wait: Callable[[], None] | None = None, max_head: int = 1 << 24, max_payload: int = 1 << 31
    ) -> tuple[bytearray, bytearray]:
        """(head, payload) of the next message; ValueError for one longer than the limits, EOFError
        when the other end is gone."""
        n_head, n_payload = FRAME.unpack(self.read(FRAME.size, on_wait))
        if n_head > max_head or n_payload > max_payload:
            raise ValueError(f"a message of {n_head} + {n_payload} bytes")
        return self.read(n_head, on_wait), self.read(n_payload, on_wait)


def split_payload(payload: bytearray, layout: Sequence[tuple[tuple[int, ...], str]]) -> list[np.ndarray]:
    """The arrays (shape, dtype string) laid end to end in ``payload``, as views of it."""
    arrays, offset = [], 0
    for shape, dtype in layout:
        dt = np.dtype(dtype)
        count = int(np.prod(shape, dtype=np.int64))
        arrays.append(np.frombuffer(payload, dt, count, offset).reshape(shape))
        offset += count * dt.itemsize
    if offset != len(payload):
        raise ValueError(f"a payload of {len(payload)} bytes for arrays of {offset}")
    return arrays


def answer_array(reply: dict[str, Any], payload: bytes | None, name: str) -> np.ndarray:
    """The array an engine-level answer's reply describes (dtype and shape checked, never objects)."""
    try:
        shape = tuple(int(x) for x in reply["shape"])
        dtype = np.dtype(str(reply["dtype"])) if reply.get("dtype") != "object" else np.dtype(object)
        count = int(np.prod(shape, dtype=np.int64))
        if count > _MAX_ELEMENTS or any(x < 0 for x in shape):
            raise ValueError(f"shape {shape}")
        if dtype.kind == "O":  # what np.asarray made of it: refused by the checks, as in-process
            return np.empty(shape, dtype)
        if dtype.kind not in ARRAY_KINDS or payload is None:
            raise ValueError(f"dtype {dtype}")
        return np.frombuffer(payload, dtype, count).reshape(shape)
    except (KeyError, TypeError, ValueError) as err:
        raise PolicyError(
            f"policy {name}: its process sent a malformed answer to act(engine) ({err})"
        ) from None


def columns_of(reply: dict[str, Any]) -> Any:
    """``episode_columns()``'s answer from the worker's reply: ``{name: array}``, values of other kinds as
    their reprs (refused as such), or an object of the type it returned instead of a dict."""
    if "not_a_dict" in reply:
        return type(str(reply["not_a_dict"]), (), {})()  # refused by episode_columns(), named by its type
    columns = {}
    for name, dtype, values in reply["columns"]:
        dt = np.dtype(str(dtype)) if dtype != "str" else None
        columns[name] = (
            np.asarray(values, dt)
            if dt is not None and dt.kind in ARRAY_KINDS
            else np.asarray([str(v) for v in values])
        )
    return columns


def counts_of(reply: dict[str, Any], name: str) -> dict[str, int]:
    """``policy.calls()``'s counts from the worker's reply."""
    try:
        return {str(k): int(v) for k, v in reply["calls"].items()}
    except (AttributeError, KeyError, TypeError, ValueError) as err:
        raise PolicyError(f"policy {name}: its process sent malformed counts ({err})") from None


def modules_of(reply: dict[str, Any], name: str) -> list[dict[str, str]]:
    """The modules the policy imported from its own folder (each ``{"file", "sha256"}``) from the
    worker's reply."""
    try:
        return [{"file": str(m["file"]), "sha256": str(m["sha256"])} for m in reply["modules"]]
    except (KeyError, TypeError) as err:
        raise PolicyError(f"policy {name}: its process sent a malformed module list ({err})") from None
