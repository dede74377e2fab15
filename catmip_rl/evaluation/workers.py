"""Worker processes: what every worker does first (end with its parent, torch's threads), and the
sandbox's worker, which plays one ``py:`` policy and holds no engine (the parent's side:
:mod:`catmip_rl.evaluation.sandbox`). Nothing the worker sends is pickled: JSON and raw array bytes."""

from __future__ import annotations

import json
import os
import sys
import time
from collections.abc import Mapping
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

from catmip_env.play import WorldNotSupported
from catmip_env.spaces import integer_action
from catmip_rl.evaluation.checked_policy import (
    CheckedEnginePolicy,
    PettingZooPolicy,
    WrappedUserPolicy,
    make_user_policy,
)
from catmip_rl.evaluation.user_policy import (
    EngineView,
    PolicyError,
    describe_failure,
    load_factory,
    parse_policy_source,
)

__all__ = ["torch_threads", "die_with_parent", "SandboxWorker", "ARRAY_KINDS"]

ARRAY_KINDS = "biufc"  # what an answer's array may hold (never objects)


def torch_threads(n: int) -> None:
    """torch's CPU threads for a command that may play a model; without torch (an env-only install,
    which plays the planners) there is nothing to set, and a model's method fails naming the extra."""
    try:
        import torch
    except ModuleNotFoundError:
        return
    torch.set_num_threads(n)


def die_with_parent(parent: int) -> None:
    """In a worker: end when process ``parent`` ends, however it ends (SIGKILL included), so that a
    killed ``catmip bench`` leaves no worker behind. Linux asks the kernel (``PR_SET_PDEATHSIG``);
    elsewhere a daemon thread polls for the parent."""
    import signal
    import threading

    if sys.platform.startswith("linux"):
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # 1: PR_SET_PDEATHSIG
        if os.getppid() != parent:  # the parent died before the call
            os._exit(1)
        return

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=watch, daemon=True, name="die-with-parent").start()


def _info(policy: WrappedUserPolicy) -> dict[str, Any]:
    hooks = [h for h in ("start_episodes", "episode_columns", "sampled") if hasattr(policy, h)]
    if isinstance(policy, PettingZooPolicy) and policy._reset is not None:
        hooks.append("reset")
    return {
        "level": "engine" if isinstance(policy, CheckedEnginePolicy) else "pettingzoo",
        "goal_mode": policy.goal_mode,
        "deterministic": getattr(policy, "deterministic", None),
        "files": list(getattr(policy, "files", None) or []) if hasattr(policy, "files") else None,
        "hooks": hooks,
    }


def _json(value: Any) -> Any:
    """An answer's key or value as JSON keeps it (str, int, bool, float, None), else its repr."""
    return value if value is None or isinstance(value, (str, int, float)) else repr(value)


class SandboxWorker:
    """The worker's end of the pipe: the policies it built (by handle), their views, one handler per
    request."""

    def __init__(self, conn: Connection) -> None:
        target, name, env_config, seed, threads, parent, path = conn.recv()
        die_with_parent(parent)
        sys.path[:] = path  # the caller's: a module policy imports as it would there
        if threads is not None:
            torch_threads(int(threads))
        self.conn, self.target, self.name, self.env_config, self.seed = conn, target, name, env_config, seed
        self.policies: dict[int, WrappedUserPolicy] = {}
        self.views: dict[int, EngineView] = {}
        self.maps: list[Any] = []

    def send(self, reply: dict[str, Any], payload: bytes | None = None) -> None:
        self.conn.send_bytes(json.dumps(reply | ({"bytes": True} if payload is not None else {})).encode())
        if payload is not None:
            self.conn.send_bytes(payload)

    def serve(self) -> None:
        """Answer requests until the parent closes the pipe or asks to close."""
        while True:
            try:
                message = self.conn.recv()
            except (EOFError, OSError):
                return
            kind, args = message[0], message[1:]
            if kind == "close":
                return
            try:
                handler = getattr(self, f"on_{kind}", None)
                if handler is None:
                    self.send({"error": f"policy {self.name}: unknown request {kind!r}"})
                else:
                    handler(*args)
            except WorldNotSupported as exc:
                self.send({"world": str(exc)})
            except PolicyError as exc:
                self.send({"error": str(exc)})
            except KeyboardInterrupt:
                return
            except BaseException as exc:  # the evaluator's own code around the policy: named, not hidden
                self.send(
                    {"error": f"policy {self.name}: in its process, {kind} failed: {describe_failure(exc)}"}
                )

    def on_hello(self) -> None:
        factory = load_factory(parse_policy_source(self.target), self.name)
        self.policies[0] = make_user_policy(factory, self.env_config, self.seed, self.name)
        self.send({"info": _info(self.policies[0])})

    def on_view(self, handle: int, path: str, spec: list, meta: dict) -> None:
        mm = np.memmap(path, np.uint8, mode="r")  # read-only: a write raises (or faults) here
        self.maps.append(mm)
        arrays = {}
        for key, shape, dtype, off in spec:
            count = int(np.prod(shape, dtype=np.int64))
            arrays[key] = np.frombuffer(mm, np.dtype(dtype), count, off).reshape(shape)
        self.views[handle] = EngineView(meta, arrays)
        self.send({})

    def on_act(self, handle: int, *dicts: dict) -> None:
        policy = self.policies[handle]
        if isinstance(policy, CheckedEnginePolicy):
            self.engine_act(policy, self.views[handle])
        else:
            self.pettingzoo_act(policy, *dicts)

    def engine_act(self, policy: CheckedEnginePolicy, view: EngineView) -> None:
        out = policy._call(policy._act, "act(engine)", view)
        try:
            actions = np.asarray(out)
        except Exception as exc:
            what = f"{type(out).__name__} ({describe_failure(exc)})"
            raise PolicyError(f"policy {self.name}: act(engine) returned {what}") from None
        if actions.dtype.kind not in ARRAY_KINDS:
            self.send({"dtype": "object", "shape": list(actions.shape)})
        else:
            actions = np.ascontiguousarray(actions)
            self.send({"dtype": actions.dtype.str, "shape": list(actions.shape)}, actions.tobytes())

    def pettingzoo_act(self, policy: PettingZooPolicy, observations: dict, infos: dict) -> None:
        out = policy._call(policy._act, "act(observations, infos)", observations, infos)
        if not isinstance(out, Mapping):
            raise PolicyError(
                f"policy {self.name}: act(observations, infos) returned {type(out).__name__}, "
                "expected a dict {robot: action}"
            )
        try:
            pairs = [[_json(k), integer_action(k, v)] for k, v in out.items()]
        except (TypeError, ValueError) as exc:
            self.send({"parse_error": " ".join(str(exc).split())})
        else:
            self.send({"actions": pairs})

    def on_reset(self, handle: int) -> None:
        self.policies[handle].reset()
        self.send({})

    def on_start_episodes(self, handle: int, num_worlds: int, num_robots: int) -> None:
        self.policies[handle].start_episodes(num_worlds, num_robots)
        self.send({})

    def on_episode_columns(self, handle: int) -> None:
        reported = self.policies[handle].episode_columns()
        if not isinstance(reported, dict):
            self.send({"not_a_dict": type(reported).__name__})
            return
        columns = []
        for key, values in reported.items():
            arr = np.asarray(values)
            if arr.dtype.kind in ARRAY_KINDS:
                columns.append([_json(key), arr.dtype.str, arr.tolist()])
            else:
                columns.append([_json(key), "str", [repr(v) for v in arr.ravel()]])
        self.send({"columns": columns})

    def on_sampled(self, handle: int, seed: int) -> None:
        new = max(self.policies) + 1
        self.policies[new] = self.policies[handle].sampled(seed)
        self.send({"handle": new, "info": _info(self.policies[new])})


if __name__ == "__main__":  # the sandbox's worker: python -m catmip_rl.evaluation.workers FD
    SandboxWorker(Connection(int(sys.argv[1]))).serve()
