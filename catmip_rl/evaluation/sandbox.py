"""A ``py:`` policy played in a worker process that holds no engine: what a leaderboard replay plays.

In-process, a policy is given read-only observations (:class:`~catmip_rl.evaluation.user_policy.EngineView`
at the engine level, new arrays at the PettingZoo level), but code in the same process can still walk the
stack or the garbage collector to the engine. Isolated, the policy's factory is imported and called in a
spawned worker; the parent keeps the engine and, at each decision, sends the worker what the protocol lets
a policy read and receives its actions:

* engine level: the :class:`~catmip_rl.evaluation.user_policy.EngineView`'s arrays, copied into a shared
  memory file the worker maps read-only (the worker's view is built from it: the same arrays, the same
  values, no ground truth), then one small message per decision;
* PettingZoo level: each decision's ``(observations, infos)`` dicts.

Nothing the worker sends is unpickled: answers come back as JSON and raw array bytes, and the parent checks
them against its own engine exactly as it checks an in-process policy's
(:class:`~catmip_rl.evaluation.checked_policy.CheckedEnginePolicy`,
:class:`~catmip_rl.evaluation.checked_policy.PettingZooPolicy`), so an honest policy's results are identical
in-process and isolated. A worker that ends (``os._exit``, a crash, a signal) is a
:class:`~catmip_rl.evaluation.user_policy.PolicyError` naming its exit code.

    from catmip_rl.evaluation.evaluate import evaluate
    result = evaluate("py:FILE.py:FACTORY", setting, episodes=1000, seed=1000, isolated=True)
    # or: Method(..., isolated=True); or isolated_policy(...) below, closed after use
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import tempfile
import weakref
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

from catmip_env.config import EnvConfig
from catmip_env.play import WorldNotSupported
from catmip_rl.evaluation.checked_policy import (
    CheckedEnginePolicy,
    PettingZooPolicy,
    WrappedUserPolicy,
)
from catmip_rl.evaluation.user_policy import (
    VIEW_ARRAYS,
    VIEW_STATE_FIELDS,
    EngineView,
    PolicyError,
)
from catmip_rl.evaluation.workers import ARRAY_KINDS

__all__ = ["isolated_policy", "close_policy", "IsolatedWorker"]

_KEYS = (*VIEW_ARRAYS, *(f"state.{f}" for f in VIEW_STATE_FIELDS), "state.target", "world.keys")
_MAX_HEADER = 1 << 24
_MAX_PAYLOAD = 1 << 31
_MAX_ELEMENTS = 1 << 28


def _view_array(view: EngineView, key: str) -> np.ndarray:
    owner, _, name = key.rpartition(".")
    return getattr({"": view, "state": view.state, "world": view.world}[owner], name)


# -- the parent's side --------------------------------------------------------------------------------------
class IsolatedWorker:
    """One spawned process playing one ``py:`` policy (and the policies its ``sampled`` makes), and the pipe
    to it. :meth:`close` ends it (also when the parent is collected or exits; a killed parent takes it
    along: :func:`~catmip_rl.evaluation.workers.die_with_parent`)."""

    def __init__(self, target: str, name: str, env_config: EnvConfig, seed: int, threads: int | None) -> None:
        # a new interpreter (python -m this module), not multiprocessing's spawn, which would import the
        # caller's __main__ again (a script without a main guard would run twice)
        self.name = name
        mine, child = socket.socketpair()
        self.conn = Connection(mine.detach())
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "catmip_rl.evaluation.workers", str(child.fileno())],
            pass_fds=(child.fileno(),),
            stdin=subprocess.DEVNULL,
        )
        child.close()
        self.conn.send((target, name, env_config, seed, threads, os.getpid(), list(sys.path)))
        self._buffers: dict[int, tuple[tuple, dict[str, np.ndarray]]] = {}  # handle -> (layout key, arrays)
        self._closed = False
        self._finalizer = weakref.finalize(self, _stop, self.conn, self.proc)

    def request(self, what: str, message: tuple) -> tuple[dict[str, Any], bytes | None]:
        """Send ``message`` (pickled: parent to worker only), receive the worker's JSON reply (and its
        bytes); PolicyError for the worker's error or its end."""
        if self._closed:
            raise PolicyError(f"policy {self.name}: its process was closed before {what}")
        try:
            self.conn.send(message)
            reply = json.loads(self.conn.recv_bytes(_MAX_HEADER))
            payload = (
                self.conn.recv_bytes(_MAX_PAYLOAD) if isinstance(reply, dict) and reply.get("bytes") else None
            )
        except (EOFError, OSError):
            self._ended(what)
        except ValueError as err:  # a reply that is not JSON, or too long
            raise PolicyError(
                f"policy {self.name}: its process sent a malformed reply to {what} ({err})"
            ) from None
        if not isinstance(reply, dict):
            raise PolicyError(f"policy {self.name}: its process sent a malformed reply to {what}")
        if "world" in reply:
            raise WorldNotSupported(str(reply["world"]))
        if "error" in reply:
            raise PolicyError(str(reply["error"]))
        return reply, payload

    def _ended(self, what: str) -> None:
        try:
            code = self.proc.wait(10)
        except subprocess.TimeoutExpired:
            code = None
        self._closed = True
        how = f"exit code {code}" if code is not None and code >= 0 else f"signal {-code}" if code else "hung"
        raise PolicyError(
            f"policy {self.name}: its process ended during {what} ({how}): a policy returns its answers "
            "and never ends the process"
        ) from None

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
        """End the worker (asked, then terminated after a few seconds) and free its shared arrays."""
        self._closed = True
        self._buffers.clear()
        self._finalizer()


def _stop(conn, proc) -> None:
    try:
        conn.send(("close",))
    except (OSError, ValueError):
        pass
    try:
        proc.wait(5)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(5)
    conn.close()


def _answer_array(reply: dict[str, Any], payload: bytes | None, name: str) -> np.ndarray:
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


def _engine_act(worker: IsolatedWorker, handle: int):
    def act(view: EngineView) -> np.ndarray:
        for key, shared in worker.share(handle, view).items():
            np.copyto(shared, _view_array(view, key))
        reply, payload = worker.request("act(engine)", ("act", handle))
        return _answer_array(reply, payload, worker.name)

    return act


def _pettingzoo_act(worker: IsolatedWorker, handle: int):
    def act(observations: dict, infos: dict) -> dict:
        reply, _ = worker.request("act(observations, infos)", ("act", handle, observations, infos))
        if "parse_error" in reply:  # as PettingZooPolicy says it of an in-process answer
            tick = next(iter(infos.values()))["tick"] if infos else "?"
            raise PolicyError(f"policy {worker.name}: {reply['parse_error']} (world 0 at tick {tick})")
        try:
            return {(k if isinstance(k, (str, int)) else str(k)): int(v) for k, v in reply["actions"]}
        except (KeyError, TypeError, ValueError) as err:
            raise PolicyError(f"policy {worker.name}: its process sent malformed actions ({err})") from None

    return act


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
        policy = PettingZooPolicy(_pettingzoo_act(worker, handle), name, goal_mode, reset)
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
        policy.episode_columns = lambda: _columns(worker, handle)
    if "sampled" in hooks:

        def sampled(seed: int):
            reply, _ = worker.request("sampled(seed)", ("sampled", handle, int(seed)))
            return _proxy(worker, int(reply["handle"]), reply["info"])

        policy.sampled = sampled
    policy.isolated = True
    policy.close = worker.close
    return policy


def _columns(worker: IsolatedWorker, handle: int) -> Any:
    reply, _ = worker.request("episode_columns()", ("episode_columns", handle))
    if "not_a_dict" in reply:
        return type(str(reply["not_a_dict"]), (), {})()  # refused by episode_columns(), named by its type
    columns = {}
    for name, dtype, values in reply["columns"]:  # values of other kinds: their reprs, refused as such
        dt = np.dtype(str(dtype)) if dtype != "str" else None
        columns[name] = (
            np.asarray(values, dt)
            if dt is not None and dt.kind in ARRAY_KINDS
            else np.asarray([str(v) for v in values])
        )
    return columns


def isolated_policy(
    target: str, name: str, env_config: EnvConfig, seed: int, threads: int | None = None
) -> CheckedEnginePolicy | PettingZooPolicy:
    """The ``py:`` policy ``target`` (``py:FILE.py:FACTORY``) built in a new worker process for
    ``env_config`` and ``seed``: the same wrapper
    :func:`~catmip_rl.evaluation.checked_policy.make_user_policy`
    gives (its ``act``, ``goal_mode``, optional members), whose policy runs in the worker. ``threads``:
    torch's threads there (default: this process's, where torch is imported). Call its ``close()`` (or
    :func:`close_policy`) when done. PolicyError / WorldNotSupported as in-process."""
    if threads is None and "torch" in sys.modules:
        threads = sys.modules["torch"].get_num_threads()
    worker = IsolatedWorker(target, name, env_config, seed, threads)
    try:
        reply, _ = worker.request("its factory", ("hello",))
        return _proxy(worker, 0, reply["info"])
    except BaseException:
        worker.close()
        raise


def close_policy(policy: Any) -> None:
    """End an isolated policy's worker (nothing for any other policy)."""
    if getattr(policy, "isolated", False):
        policy.close()
