"""What bounds someone else's code played isolated (:mod:`~catmip_rl.evaluation.sandbox`): its time per
call, its memory, the processes it starts and the folder it writes in.

* **Time.** A decision may take :data:`DECISION_LIMIT_S` plus :data:`DECISION_LIMIT_PER_ROBOT_S` per
  robot deciding at it (an engine-level decision of 1,000 worlds has thousands; a planner takes
  milliseconds per robot); the factory, which loads weights, :data:`FACTORY_LIMIT_S`. The parent waits on
  the pipe with a timeout and never signals the policy's code; past the limit it ends the worker and
  raises :class:`~catmip_rl.evaluation.user_policy.PolicyError` ("took longer than N s at act(engine)").
* **Memory.** The resident memory of the worker and the processes it started (``VmRSS``, read from
  ``/proc/PID/statm``: no address-space limit, which torch and numba do not survive), read while the
  parent waits and after each reply (at most every 0.1 s; the processes re-listed each second), may not
  pass :data:`MEMORY_LIMIT_BYTES`. Where there is no ``/proc`` (macOS, Windows) memory is not watched;
  the time limit still holds.
* **Processes.** The worker is a child subreaper (Linux ``PR_SET_CHILD_SUBREAPER``, no privilege
  needed): whatever the policy starts, detached ones included (a double fork, ``setsid``), stays one of
  its descendants while it lives. Every process it starts also inherits the marker :data:`MARKER` in its
  environment. At the end the parent stops, then kills, the worker, its descendants, the descendants it
  saw while waiting and every process whose environment holds the worker's marker (so a worker that died
  first leaves none of them behind, unless a process both left its tree and cleared its environment).
  Elsewhere the worker's own session (process group) is killed. A ``catmip`` that is itself killed takes
  its worker along (``PR_SET_PDEATHSIG``), not the processes the worker started.
* **Folder.** The worker runs in a fresh temporary folder (its working directory, ``HOME`` and
  ``TMPDIR`` inside it), removed at the end: relative writes land there. The policy's own files are found
  by absolute paths (the ``py:`` file resolved, ``sys.path`` passed as absolute paths).

Overriding a limit: set the constant before the policy is made (``bounds.DECISION_LIMIT_S = 60.0``), or
give :func:`~catmip_rl.evaluation.sandbox.isolated_policy` a :class:`Limits`. Out of scope: code that
signals other processes of the same user (a worker may ``kill`` any of them, as any program may).
"""

from __future__ import annotations

import ctypes
import os
import shutil
import signal
import sys
import tempfile
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "DECISION_LIMIT_S",
    "DECISION_LIMIT_PER_ROBOT_S",
    "FACTORY_LIMIT_S",
    "MEMORY_LIMIT_BYTES",
    "MARKER",
    "Limits",
    "PolicyProcesses",
    "become_subreaper",
    "end_descendants",
    "working_folder",
    "remove_folder",
    "worker_environment",
]

DECISION_LIMIT_S = 10.0
"""Seconds a call of the policy may take (``act``, ``reset()``, ``start_episodes``, ...), plus ..."""
DECISION_LIMIT_PER_ROBOT_S = 0.25
"""... seconds per robot deciding at that call (active robots of live worlds)."""
FACTORY_LIMIT_S = 120.0
"""Seconds the factory (and ``sampled(seed)``, which may build a model) may take: it loads weights."""
MEMORY_LIMIT_BYTES = 8 << 30
"""Resident bytes of the worker and the processes it started together (8 GiB)."""
MARKER = "CATMIP_POLICY_SANDBOX"
"""The environment variable whose value names one worker's processes."""

_PROC = Path("/proc")
_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096
_WATCH_S = 0.1  # resident memory read at most this often
_WALK_S = 1.0  # the worker's descendants re-listed at most this often


@dataclass(frozen=True)
class Limits:
    """The bounds of one worker (the module's constants, read when it starts: :meth:`current`)."""

    decision_s: float
    """Seconds of a call of the policy, plus ``per_robot_s`` per deciding robot."""
    per_robot_s: float
    """Seconds per robot deciding at a call."""
    factory_s: float
    """Seconds of the factory and of ``sampled(seed)``."""
    memory_bytes: int
    """Resident bytes of the worker and its descendants."""

    @classmethod
    def current(cls) -> Limits:
        return cls(DECISION_LIMIT_S, DECISION_LIMIT_PER_ROBOT_S, FACTORY_LIMIT_S, MEMORY_LIMIT_BYTES)

    def decision(self, robots: int) -> float:
        """Seconds of a call at which ``robots`` robots decide."""
        return self.decision_s + self.per_robot_s * max(int(robots), 0)


# -- processes, read from /proc (Linux) ----------------------------------------------------------------------
def _stat(pid: int) -> tuple[int, int] | None:
    """(parent pid, start time in clock ticks) of a live process, None for a gone or zombie one."""
    try:
        text = (_PROC / str(pid) / "stat").read_bytes()
    except OSError:
        return None
    fields = text.rpartition(b")")[2].split()  # the name, in parentheses, may hold anything
    if len(fields) < 20 or fields[0] in (b"Z", b"X"):
        return None
    return int(fields[1]), int(fields[19])


def _processes() -> dict[int, tuple[int, int]]:
    """Every live process: pid -> (parent pid, start time)."""
    try:
        pids = [int(p) for p in os.listdir(_PROC) if p.isdigit()]
    except OSError:
        return {}
    found = {}
    for pid in pids:
        st = _stat(pid)
        if st is not None:
            found[pid] = st
    return found


def _descendants(root: int, table: dict[int, tuple[int, int]]) -> set[int]:
    children: dict[int, list[int]] = {}
    for pid, (ppid, _) in table.items():
        children.setdefault(ppid, []).append(pid)
    found, todo = set(), [root]
    while todo:
        for child in children.get(todo.pop(), ()):
            if child not in found:
                found.add(child)
                todo.append(child)
    return found


def _marked(token: str, pids: Iterable[int]) -> set[int]:
    """The processes among ``pids`` whose environment holds ``MARKER=token`` (those of other users are
    not readable, and not ours)."""
    entry = f"\0{MARKER}={token}\0".encode()
    found = set()
    for pid in pids:
        try:
            if entry in b"\0" + (_PROC / str(pid) / "environ").read_bytes():
                found.add(pid)
        except OSError:
            continue
    return found


def _resident(pid: int) -> int:
    try:
        return int((_PROC / str(pid) / "statm").read_bytes().split()[1]) * _PAGE
    except (OSError, IndexError, ValueError):
        return 0


def _signal_all(pids: Iterable[int], sig: int) -> None:
    for pid in pids:
        try:
            os.kill(pid, sig)
        except (ProcessLookupError, PermissionError):
            pass


class PolicyProcesses:
    """The parent's record of one worker (``pid``, marked ``token``) and the processes it started: what
    :meth:`resident_bytes` measures and :meth:`end` ends."""

    def __init__(self, pid: int, token: str) -> None:
        self.pid, self.token = pid, token
        self.linux = _PROC.is_dir() and sys.platform.startswith("linux")
        self.seen: dict[int, int] = {}  # descendant pid -> its start time (a reused pid is not ours)
        self._read = self._walked = 0.0

    def _walk(self) -> None:
        table = _processes()
        for pid in _descendants(self.pid, table):
            self.seen.setdefault(pid, table[pid][1])
        self._walked = time.monotonic()

    def resident_bytes(self, force: bool = False) -> int | None:
        """Resident bytes of the worker and the descendants seen (re-listed each second), or None when
        not due (read at most every 0.1 s unless ``force``) or not measurable (no ``/proc``)."""
        now = time.monotonic()
        if not self.linux or (not force and now - self._read < _WATCH_S):
            return None
        if now - self._walked >= _WALK_S:
            self._walk()
        self._read = now
        return _resident(self.pid) + sum(_resident(p) for p in self.seen)

    def end(self) -> None:
        """Stop (SIGSTOP: none of them can start more), then kill, the worker, its descendants, those
        seen before and every process marked with the token; repeated until no new one appears."""
        if not self.linux:
            for kill in (
                lambda: os.killpg(self.pid, signal.SIGKILL),
                lambda: os.kill(self.pid, signal.SIGKILL),
            ):
                try:
                    kill()
                except (ProcessLookupError, PermissionError):
                    pass
            return
        stopped: set[int] = set()
        for _ in range(20):
            table = _processes()
            ours = {p for p, start in self.seen.items() if p in table and table[p][1] == start}
            found = _descendants(self.pid, table) | ours | _marked(self.token, table)
            found |= {self.pid} if self.pid in table else set()
            found.discard(os.getpid())
            new = found - stopped
            if not new:
                break
            _signal_all(new, signal.SIGSTOP)
            stopped |= new
        _signal_all(stopped, signal.SIGKILL)  # a stopped process dies of it too


# -- the worker's side ---------------------------------------------------------------------------------------
def not_dumpable() -> None:
    """In the process that plays a worker's policy: no other process of this user may read its memory
    (``/proc/PID/mem``: the maps it holds, a check's seed) unless it has ``CAP_SYS_PTRACE``, which
    :func:`drop_ptrace` takes from the worker (Linux; elsewhere nothing is done)."""
    if sys.platform.startswith("linux"):
        ctypes.CDLL(None, use_errno=True).prctl(4, 0, 0, 0, 0)  # 4: PR_SET_DUMPABLE


class _CapHeader(ctypes.Structure):
    _fields_ = [("version", ctypes.c_uint32), ("pid", ctypes.c_int)]


class _CapData(ctypes.Structure):
    _fields_ = [(name, ctypes.c_uint32) for name in ("effective", "permitted", "inheritable")]


def drop_ptrace() -> None:
    """In the worker, before the policy is imported: give up ``CAP_SYS_PTRACE`` (held by root), so that
    the policy cannot read its evaluator's memory (:func:`not_dumpable`) nor any child regain it
    (Linux; a process that never had it loses nothing)."""
    if not sys.platform.startswith("linux"):
        return
    libc, cap = ctypes.CDLL(None, use_errno=True), 19  # 19: CAP_SYS_PTRACE
    head, data = _CapHeader(0x20080522, 0), (_CapData * 2)()  # _LINUX_CAPABILITY_VERSION_3
    if libc.capget(ctypes.byref(head), data) == 0:
        data[0].effective &= ~(1 << cap)
        data[0].permitted &= ~(1 << cap)
        libc.capset(ctypes.byref(head), data)
    libc.prctl(24, cap, 0, 0, 0)  # 24: PR_CAPBSET_DROP (fails without CAP_SETPCAP: then none to drop)


def become_subreaper() -> bool:
    """Make this process a child subreaper (Linux): orphans of its descendants become its children, not
    init's, so every process it started stays in its tree. False where not available."""
    if not sys.platform.startswith("linux"):
        return False
    import ctypes

    return ctypes.CDLL(None, use_errno=True).prctl(36, 1, 0, 0, 0) == 0  # 36: PR_SET_CHILD_SUBREAPER


def end_descendants() -> None:
    """In the worker: stop, then kill, every process it started (its whole tree: it is a subreaper)."""
    if not _PROC.is_dir():
        return
    me, stopped = os.getpid(), set()
    for _ in range(20):
        new = _descendants(me, _processes()) - stopped
        if not new:
            break
        _signal_all(new, signal.SIGSTOP)
        stopped |= new
    _signal_all(stopped, signal.SIGKILL)


# -- the folder and the environment --------------------------------------------------------------------------
def working_folder() -> Path:
    """A fresh temporary folder for a worker, with ``home`` and ``tmp`` inside (remove it with
    :func:`shutil.rmtree` when the worker has ended)."""
    folder = Path(tempfile.mkdtemp(prefix="catmip-policy-"))
    (folder / "home").mkdir()
    (folder / "tmp").mkdir()
    return folder


def remove_folder(folder: Path) -> None:
    shutil.rmtree(folder, ignore_errors=True)


def worker_environment(folder: Path, token: str, path: list[str]) -> dict[str, str]:
    """This process's environment (less Ray's ``RAY_*`` variables) for a worker in ``folder``: ``HOME``
    and ``TMPDIR`` inside it, the marker, and ``PYTHONPATH`` = this process's ``sys.path`` (absolute), so
    that it imports what this process imports from any working directory."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_")}  # no way to its Ray cluster
    env.update(HOME=str(folder / "home"), TMPDIR=str(folder / "tmp"), **{MARKER: token})
    env["PYTHONPATH"] = os.pathsep.join(path)
    return env
