"""A ``py:`` policy played in a worker process that holds no engine: how every ``py:`` policy plays
(``catmip eval``, ``bench suite``, ``bench paper``, ``render``, a leaderboard replay).

In-process, a policy is given read-only observations (:class:`~catmip_rl.evaluation.user_policy.EngineView`
at the engine level, new arrays at the PettingZoo level), but code in the same process can still walk the
stack or the garbage collector to the engine. Isolated, the policy's factory is imported and called in a
new worker process (:class:`~catmip_rl.evaluation.workers.SandboxWorker`); the parent keeps the engine
and, at each decision, sends the worker what the protocol lets a policy read and receives its actions:

* engine level: the :class:`~catmip_rl.evaluation.user_policy.EngineView`'s arrays, copied into a shared
  memory file the worker maps read-only (the worker's view is built from it: the same arrays, the same
  values, no ground truth), then one small message per decision;
* PettingZoo level: the world's observation rows as raw bytes (no pickled dicts), from which the worker
  builds ``(observations, infos)`` with the functions the parent uses in-process.

Nothing the worker sends is unpickled: answers come back as JSON and raw array bytes, and the parent checks
them against its own engine exactly as it checks an in-process policy's
(:class:`~catmip_rl.evaluation.checked_policy.CheckedEnginePolicy`,
:class:`~catmip_rl.evaluation.checked_policy.PettingZooPolicy`), so an honest policy's results are identical
in-process and isolated. The worker is bounded (:mod:`~catmip_rl.evaluation.bounds`: time per call,
memory, the processes it starts, its folder); a worker that ends (``os._exit``, a crash, a signal) or
passes a bound is a :class:`~catmip_rl.evaluation.user_policy.PolicyError` in one line naming the policy.
``policy.calls()`` says which of the project's entry points it called
(:mod:`~catmip_rl.evaluation.call_counts`).

    from catmip_rl.evaluation.evaluate import evaluate
    result = evaluate("py:FILE.py:FACTORY", setting, episodes=1000, seed=1000)  # isolated
    result = evaluate("py:FILE.py:FACTORY", setting, isolated=False)  # in-process: tests, a debugger

In-process play (``isolated=False``, ``Method(..., isolated=False)``) is for tests and for debugging a
policy (a breakpoint in ``act``); an object given to ``evaluate(policy=...)`` lives in the caller's
process and plays there.
"""

from __future__ import annotations

import json
import os
import pickle
import secrets
import socket
import subprocess
import sys
import tempfile
import time
import weakref
from pathlib import Path
from typing import Any

import numpy as np

from catmip_env.config import EnvConfig
from catmip_env.play import WorldNotSupported
from catmip_rl.evaluation.bounds import (
    Limits,
    PolicyProcesses,
    not_dumpable,
    remove_folder,
    worker_environment,
    working_folder,
)
from catmip_rl.evaluation.checked_policy import (
    CheckedEnginePolicy,
    PettingZooPolicy,
    WrappedUserPolicy,
)
from catmip_rl.evaluation.pipe import (
    FrameReader,
    answer_array,
    columns_of,
    counts_of,
    modules_of,
    send_frame,
    wait_in_slices,
)
from catmip_rl.evaluation.user_policy import (
    VIEW_ARRAYS,
    VIEW_STATE_FIELDS,
    EngineView,
    PolicyError,
    parse_policy_source,
)

__all__ = ["isolated_policy", "close_policy", "IsolatedWorker"]

_KEYS = (*VIEW_ARRAYS, *(f"state.{f}" for f in VIEW_STATE_FIELDS), "state.target", "world.keys")
_MAX_HEADER = 1 << 24
_MAX_PAYLOAD = 1 << 31
_SLICE_S = 0.1  # the parent's wait on the pipe: the bounds are checked this often
_CLOSE_WAIT_S = 5.0  # a worker asked to close has this long before it is killed


def _view_array(view: EngineView, key: str) -> np.ndarray:
    owner, _, name = key.rpartition(".")
    return getattr({"": view, "state": view.state, "world": view.world}[owner], name)


# -- the parent's side --------------------------------------------------------------------------------------
class IsolatedWorker:
    """One worker process playing one ``py:`` policy (and the policies its ``sampled`` makes), and the pipe
    to it. :meth:`close` ends it, and every process it started, and removes its folder (also when the
    parent is collected or exits; a killed parent takes the worker along:
    :func:`~catmip_rl.evaluation.workers.die_with_parent`)."""

    def __init__(
        self,
        target: str,
        name: str,
        env_config: EnvConfig,
        seed: int,
        threads: int | None,
        limits: Limits | None = None,
    ) -> None:
        # a new interpreter (python -m), not multiprocessing's spawn, which would import the caller's
        # __main__ again (a script without a main guard would run twice); in its own session and folder
        self.name = name
        self.limits = Limits.current() if limits is None else limits
        not_dumpable()  # this process holds the world: its memory is not the policy's to read
        self.folder = working_folder()
        token = secrets.token_hex(8)
        path = [os.path.abspath(p) if p else os.getcwd() for p in sys.path]  # absolute: its cwd is elsewhere
        mine, child = socket.socketpair()
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "catmip_rl.evaluation.workers", str(child.fileno())],
                pass_fds=(child.fileno(),),
                stdin=subprocess.DEVNULL,
                cwd=self.folder,
                env=worker_environment(self.folder, token, path),
                start_new_session=True,
            )
        except BaseException:
            mine.close()
            remove_folder(self.folder)
            raise
        finally:
            child.close()
        wait_in_slices(mine, _SLICE_S)
        self.sock, self.reader = mine, FrameReader(mine)
        self.processes = PolicyProcesses(self.proc.pid, token)
        self._buffers: dict[int, tuple[tuple, dict[str, np.ndarray]]] = {}  # handle -> (layout key, arrays)
        self._closed = self._pending = False
        self._finalizer = weakref.finalize(self, _stop, mine, self.proc, self.processes, self.folder)
        try:  # a few bytes into an empty pipe: never waits
            send_frame(mine, pickle.dumps((target, name, env_config, seed, threads, os.getpid(), path)))
        except OSError:
            pass  # the first request reports the worker's end

    def request(
        self, what: str, message: tuple, parts: tuple = (), limit_s: float | None = None
    ) -> tuple[dict[str, Any], bytearray]:
        """Send ``message`` (pickled: parent to worker only) and the raw bytes of ``parts``, receive the
        worker's JSON reply and its bytes. PolicyError for the worker's error, its end, or a bound passed:
        the reply later than ``limit_s`` (default :attr:`Limits.decision_s`) or the memory over its limit."""
        if self._closed:
            raise PolicyError(f"policy {self.name}: its process was closed before {what}")
        limit = self.limits.decision_s if limit_s is None else float(limit_s)
        deadline = time.monotonic() + limit

        def waiting() -> None:
            if self.proc.poll() is not None:  # gone, though a process it forked may hold the pipe open
                raise EOFError
            if time.monotonic() > deadline:
                self._end()
                raise PolicyError(
                    f"policy {self.name}: took longer than {limit:g} s at {what}; its process was ended "
                    "(the limits: catmip_rl.evaluation.bounds)"
                )
            self._watch_memory(what)

        self._pending = True  # until its reply is read: a request interrupted here leaves the pipe mid-way
        try:
            send_frame(self.sock, pickle.dumps(message), parts, waiting)
            head, payload = self.reader.frame(waiting, _MAX_HEADER, _MAX_PAYLOAD)
            self._pending = False
            reply = json.loads(head)
        except PolicyError:
            raise
        except (EOFError, OSError):
            self._ended(what)
        except ValueError as err:  # a reply that is not JSON, or too long
            self._end()
            raise PolicyError(
                f"policy {self.name}: its process sent a malformed reply to {what} ({err})"
            ) from None
        self._watch_memory(what)
        if not isinstance(reply, dict):
            raise PolicyError(f"policy {self.name}: its process sent a malformed reply to {what}")
        if "world" in reply:
            raise WorldNotSupported(str(reply["world"]))
        if "error" in reply:
            raise PolicyError(str(reply["error"]))
        return reply, payload

    def _watch_memory(self, what: str) -> None:
        used = self.processes.resident_bytes()
        if used is not None and used > self.limits.memory_bytes:
            self._end()
            gib = 1 << 30
            raise PolicyError(
                f"policy {self.name}: its process used {used / gib:.1f} GiB of memory at {what}, over the "
                f"limit of {self.limits.memory_bytes / gib:g} GiB; it was ended (the limits: "
                "catmip_rl.evaluation.bounds)"
            )

    def _ended(self, what: str) -> None:
        try:
            code = self.proc.wait(2)
        except subprocess.TimeoutExpired:
            code = None
        self._end()
        how = (
            "it closed its pipe" if code is None else f"exit code {code}" if code >= 0 else f"signal {-code}"
        )
        raise PolicyError(
            f"policy {self.name}: its process ended during {what} ({how}): a policy returns its answers "
            "and never ends the process"
        ) from None

    def _end(self) -> None:
        """End the worker now (no asking), and all it started."""
        self._closed = True
        self.processes.end()
        self.close()

    def share(self, handle: int, view: EngineView) -> dict[str, np.ndarray]:
        """The shared arrays ``view``'s are copied into for the worker of ``handle``; created (a file the
        worker maps read-only, unlinked once mapped) for the first view and whenever the shapes change."""
        layout = tuple((k, _view_array(view, k).shape, _view_array(view, k).dtype.str) for k in _KEYS)
        held = self._buffers.get(handle)
        if held is not None and held[0] == layout:
            return held[1]
        offsets, size = [], 0
        for _key, shape, dtype in layout:
            offsets.append(size)
            size += -(-int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize // 64) * 64
        folder = "/dev/shm" if os.path.isdir("/dev/shm") else None
        fd, path = tempfile.mkstemp(prefix="catmip-view-", dir=folder)
        try:
            os.ftruncate(fd, max(size, 64))
            mm = np.memmap(path, np.uint8, mode="r+", shape=(max(size, 64),))
            arrays = {
                key: np.frombuffer(mm, np.dtype(dtype), int(np.prod(shape, dtype=np.int64)), off).reshape(
                    shape
                )
                for (key, shape, dtype), off in zip(layout, offsets)
            }
            meta = {
                "cfg": view.cfg,
                "goal_mode": view.goal_mode,
                "num_actions": view.num_actions,
                "stay_action": view.stay_action,
            }
            spec = [(key, shape, dtype, off) for (key, shape, dtype), off in zip(layout, offsets)]
            self.request("act(engine)", ("view", handle, path, spec, meta))
        finally:
            os.close(fd)
            os.unlink(path)  # mapped on both sides: nothing left behind, whatever happens next
        self._buffers[handle] = (layout, arrays)
        return arrays

    def close(self) -> None:
        """End the worker (asked, then killed after a few seconds; at once if a request was interrupted,
        e.g. by Ctrl-C: it may be deep in the policy's call), every process it started, and remove its
        folder."""
        if self._pending and not self._closed:
            self.processes.end()
        self._closed = True
        self._buffers.clear()
        self._finalizer()


def _stop(sock: socket.socket, proc: subprocess.Popen, processes: PolicyProcesses, folder: Path) -> None:
    try:
        send_frame(sock, pickle.dumps(("close",)))
    except (OSError, ValueError):
        pass
    try:
        proc.wait(_CLOSE_WAIT_S)
    except subprocess.TimeoutExpired:
        pass
    processes.end()  # the worker if it is still there, whatever it started, wherever it went
    try:
        proc.wait(_CLOSE_WAIT_S)
    except subprocess.TimeoutExpired:
        pass
    sock.close()
    remove_folder(folder)


def _engine_act(worker: IsolatedWorker, handle: int):
    def act(view: EngineView) -> np.ndarray:
        for key, shared in worker.share(handle, view).items():
            np.copyto(shared, _view_array(view, key))
        robots = int(np.count_nonzero(view.active & ~view.state.done[:, None]))
        reply, payload = worker.request("act(engine)", ("act", handle), (), worker.limits.decision(robots))
        return answer_array(reply, payload, worker.name)

    return act


class _IsolatedPettingZoo(PettingZooPolicy):
    """A PettingZoo-level policy in a worker: each world's decision sends its observation rows (raw bytes,
    their layout when it changes) and receives the actions."""

    def __init__(self, worker: IsolatedWorker, handle: int, goal_mode: str, reset: Any) -> None:
        super().__init__(None, worker.name, goal_mode, reset)
        self._worker, self._handle, self._layout = worker, handle, None

    def ask(self, engine: Any, b: int, agents: list[str], event_ticks: int) -> dict:
        st, active = engine.state, engine.active[b]
        arrays = (engine.obs_global[b], engine.obs_local[b], st.cls[b], engine.masks[b], active, st.comp[b])
        layout = (tuple((a.shape, a.dtype.str) for a in arrays), engine.cfg.num_classes)
        tick = int(st.ticks[b])
        message = ("pz", self._handle, tick, event_ticks, None if layout == self._layout else layout)
        limit = self._worker.limits.decision(int(active.sum()))
        reply, _ = self._worker.request("act(observations, infos)", message, arrays, limit)
        self._layout = layout
        if "parse_error" in reply:  # as PettingZooPolicy says it of an in-process answer
            raise PolicyError(f"policy {self.name}: {reply['parse_error']} (world {b} at tick {tick})")
        try:
            return {(k if isinstance(k, (str, int)) else str(k)): int(v) for k, v in reply["actions"]}
        except (KeyError, TypeError, ValueError) as err:
            raise PolicyError(f"policy {self.name}: its process sent malformed actions ({err})") from None


def _proxy(
    worker: IsolatedWorker, handle: int, info: dict[str, Any]
) -> CheckedEnginePolicy | PettingZooPolicy:
    """The parent's policy for the worker's policy ``handle``: the in-process wrapper (its checks against
    the engine, its messages) around calls to the worker."""
    name, goal_mode, hooks = worker.name, str(info["goal_mode"]), set(info.get("hooks", ()))
    policy: CheckedEnginePolicy | PettingZooPolicy
    if info["level"] == "engine":
        policy = CheckedEnginePolicy(_engine_act(worker, handle), name, goal_mode)
    else:
        reset = (lambda: worker.request("reset()", ("reset", handle)) and None) if "reset" in hooks else None
        policy = _IsolatedPettingZoo(worker, handle, goal_mode, reset)
    if isinstance(info.get("deterministic"), bool):
        policy.deterministic = info["deterministic"]
    if info.get("files") is not None:
        policy.files = WrappedUserPolicy._files(policy, list(info["files"]))
    if "start_episodes" in hooks:
        policy.start_episodes = lambda b, n: (
            worker.request(
                "start_episodes(num_worlds, num_robots)", ("start_episodes", handle, int(b), int(n))
            )
            and None
        )
    if "episode_columns" in hooks:
        policy.episode_columns = lambda: columns_of(
            worker.request("episode_columns()", ("episode_columns", handle))[0]
        )
    if "sampled" in hooks:

        def sampled(seed: int):
            message = ("sampled", handle, int(seed))
            reply, _ = worker.request("sampled(seed)", message, (), worker.limits.factory_s)
            return _proxy(worker, int(reply["handle"]), reply["info"])

        policy.sampled = sampled
    policy.calls = lambda: counts_of(worker.request("calls()", ("calls",))[0], name)
    policy.modules = lambda: modules_of(worker.request("modules()", ("modules",))[0], name)
    policy.isolated = True
    policy.close = worker.close
    return policy


def isolated_policy(
    target: str,
    name: str,
    env_config: EnvConfig,
    seed: int,
    threads: int | None = None,
    limits: Limits | None = None,
) -> CheckedEnginePolicy | PettingZooPolicy:
    """The ``py:`` policy ``target`` (``py:FILE.py:FACTORY``) built in a new worker process for
    ``env_config`` and ``seed``: the same wrapper
    :func:`~catmip_rl.evaluation.checked_policy.make_user_policy`
    gives (its ``act``, ``goal_mode``, optional members, and ``calls()``), whose policy runs in the worker.
    ``threads``: torch's threads there (default: this process's, where torch is imported); ``limits``: its
    bounds (default: :meth:`Limits.current`). Call its ``close()`` (or :func:`close_policy`) when done.
    PolicyError / WorldNotSupported as in-process."""
    target = str(parse_policy_source(target))  # a file by its absolute path: the worker runs elsewhere
    if threads is None and "torch" in sys.modules:
        threads = sys.modules["torch"].get_num_threads()
    worker = IsolatedWorker(target, name, env_config, seed, threads, limits)
    try:
        reply, _ = worker.request("the factory", ("hello",), (), worker.limits.factory_s)
        return _proxy(worker, 0, reply["info"])
    except BaseException:
        worker.close()
        raise


def close_policy(policy: Any) -> None:
    """End an isolated policy's worker (nothing for any other policy)."""
    if getattr(policy, "isolated", False):
        policy.close()
