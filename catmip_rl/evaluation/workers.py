"""Worker processes: what every worker does first (end with its parent, torch's threads), and the
sandbox's worker, which plays one ``py:`` policy and holds no engine (the parent's side:
:mod:`catmip_rl.evaluation.sandbox`; the pipe between them: :mod:`catmip_rl.evaluation.pipe`; its
bounds: :mod:`catmip_rl.evaluation.bounds`). The parent's messages are pickled (the parent is trusted);
nothing the worker sends is: JSON and raw array bytes."""

from __future__ import annotations

import json
import os
import pickle
import socket
import sys
import time
from collections.abc import Mapping, Sequence
from types import SimpleNamespace
from typing import Any

import numpy as np

from catmip_env.envs.spaces import integer_action
from catmip_env.play import WorldNotSupported
from catmip_rl.evaluation.bounds import become_subreaper, drop_ptrace, end_descendants
from catmip_rl.evaluation.call_counts import install_counters
from catmip_rl.evaluation.checked_policy import (
    CheckedEnginePolicy,
    PettingZooPolicy,
    WrappedUserPolicy,
    make_user_policy,
    pettingzoo_inputs,
)
from catmip_rl.evaluation.pipe import ARRAY_KINDS, FrameReader, send_frame, split_payload
from catmip_rl.evaluation.user_policy import (
    EngineView,
    PolicyError,
    describe_failure,
    load_factory,
    parse_policy_source,
)

__all__ = ["torch_threads", "die_with_parent", "SandboxWorker"]


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


# -- the sandbox's worker ------------------------------------------------------------------------------------
def _info(policy: WrappedUserPolicy) -> dict[str, Any]:
    hooks = [h for h in ("start_episodes", "episode_columns", "sampled") if hasattr(policy, h)]
    if isinstance(policy, PettingZooPolicy):  # every episode from a fresh copy: reset before each
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


def _one_world(arrays: list[np.ndarray], tick: int, num_classes: int) -> SimpleNamespace:
    """What :func:`~catmip_rl.evaluation.checked_policy.pettingzoo_inputs` reads of an engine, for one
    world, from the arrays the parent sent (its ``obs_global``, ``obs_local``, ``cls``, ``masks``,
    ``active``, ``comp`` rows)."""
    og, ol, cls, masks, active, comp = (a[None] for a in arrays)
    state = SimpleNamespace(cls=cls, comp=comp, ticks=np.array([tick], np.int64))
    world = SimpleNamespace(obs_global=og, obs_local=ol, state=state)
    cfg = SimpleNamespace(num_classes=num_classes)
    return SimpleNamespace(cfg=cfg, world=world, state=state, masks=masks, active=active)


class SandboxWorker:
    """The worker's end of the pipe: the policies it built (by handle), their views, one handler per
    request. It is a child subreaper (every process the policy starts stays its descendant, and is ended
    with it), and it counts the project's entry points the policy calls
    (:mod:`~catmip_rl.evaluation.call_counts`, installed before the factory is imported)."""

    def __init__(self, sock: socket.socket) -> None:
        self.reader = FrameReader(sock)
        head, _ = self.reader.frame()
        target, name, env_config, seed, threads, parent, path = pickle.loads(head)
        die_with_parent(parent)
        become_subreaper()
        drop_ptrace()  # the evaluator is not dumpable: the policy cannot read its memory
        sys.path[:] = path  # the caller's, absolute: a module policy imports as it would there
        if threads is not None:
            torch_threads(int(threads))
        self.calls = install_counters()
        self.sock, self.target, self.name, self.env_config, self.seed = sock, target, name, env_config, seed
        self.policies: dict[int, WrappedUserPolicy] = {}
        self.views: dict[int, EngineView] = {}
        self.layouts: dict[int, tuple] = {}  # PettingZoo-level handle -> (its arrays' layout, classes)
        self.maps: list[Any] = []
        self.payload = bytearray()

    def send(self, reply: dict[str, Any], parts: Sequence[Any] = ()) -> None:
        send_frame(self.sock, json.dumps(reply).encode(), parts)

    def serve(self) -> None:
        """Answer requests until the parent closes the pipe or asks to close; then end every process the
        policy started, and this one (no exit handler of the policy's runs)."""
        try:
            self._serve()
        finally:
            end_descendants()
            for stream in (sys.stdout, sys.stderr):
                try:
                    stream.flush()
                except Exception:
                    pass
            os._exit(0)

    def _serve(self) -> None:
        while True:
            try:
                head, self.payload = self.reader.frame()
                message = pickle.loads(head)
            except (EOFError, OSError, ValueError, KeyboardInterrupt):
                return
            kind, args = message[0], message[1:]
            if kind == "close":
                return
            try:
                self.calls.check()
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

    def on_calls(self) -> None:
        self.send({"calls": self.calls()})

    def on_modules(self) -> None:
        from catmip_rl.evaluation.methods import own_modules  # the policy's imports: this process's

        self.send({"modules": own_modules(self.target)})

    def on_view(self, handle: int, path: str, spec: list, meta: dict) -> None:
        mm = np.memmap(path, np.uint8, mode="r")  # read-only: a write raises (or faults) here
        self.maps.append(mm)
        arrays = {}
        for key, shape, dtype, off in spec:
            count = int(np.prod(shape, dtype=np.int64))
            arrays[key] = np.frombuffer(mm, np.dtype(dtype), count, off).reshape(shape)
        self.views[handle] = EngineView(meta, arrays)
        self.send({})

    def on_act(self, handle: int) -> None:
        """An engine-level decision on the view the parent has just filled."""
        policy = self.policies[handle]
        out = policy._call(policy._act, "act(engine)", self.views[handle])
        try:
            actions = np.asarray(out)
        except Exception as exc:
            what = f"{type(out).__name__} ({describe_failure(exc)})"
            raise PolicyError(f"policy {self.name}: act(engine) returned {what}") from None
        if actions.dtype.kind not in ARRAY_KINDS:
            self.send({"dtype": "object", "shape": list(actions.shape)})
        else:
            self.send({"dtype": actions.dtype.str, "shape": list(actions.shape)}, [actions])

    def on_pz(self, handle: int, tick: int, event_ticks: int, layout: tuple | None) -> None:
        """A PettingZoo-level decision of one world: its arrays in the payload (laid out as ``layout``
        says, or as last time), its ``(observations, infos)`` built from them as the parent builds
        them in-process (:func:`~catmip_rl.evaluation.checked_policy.pettingzoo_inputs`)."""
        if layout is not None:
            self.layouts[handle] = layout
        arrays, num_classes = self.layouts[handle]
        engine = _one_world(split_payload(self.payload, arrays), tick, num_classes)
        agents = [f"robot_{i}" for i in range(engine.active.shape[1])]
        observations, infos = pettingzoo_inputs(engine, 0, agents, event_ticks)
        policy = self.policies[handle]
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
    SandboxWorker(socket.socket(fileno=int(sys.argv[1]))).serve()
