"""Your own policy on the paper's protocol: ``--method NAME=py:FILE.py:FACTORY`` (or
``py:package.module:FACTORY``) in ``catmip eval``, ``catmip render`` and ``catmip bench paper``, and
``evaluate(policy=...)`` in Python. Guide: docs/benchmark-your-algorithm.md.

``FACTORY(env_config, seed)`` gets the evaluation's :class:`~catmip_env.config.EnvConfig` (the task with
the setting's communication, noise and macro-action length, evaluation activation (0, 0)) and the map
set's seed, and returns a policy at one of two levels:

* **PettingZoo level** -- ``act(observations, infos) -> {robot: action}``, exactly the dicts one world of
  ``search_rescue_v0.parallel_env(level="macro")`` gives (``obs_format="dict"``), called at each decision
  event; only the active robots' actions count (``infos[r]["active"] == 1``), the others may be left
  out. Episodes are played one after another, and ``reset()``, if the policy has it, is called before
  each, so a policy with memory works as it would in a PettingZoo loop.
* **Engine level** (fast, batched) -- ``act(engine) -> (B, N) int`` goal actions for every world of a
  :class:`~catmip_env.engines.events.EventEngine` (the :class:`catmip_env.play.Policy` protocol, what the
  planners and AMAT implement); all maps of a setting are played at once.

The level is read from the policy's ``level`` attribute (``"pettingzoo"`` or ``"engine"``) or else from
``act``'s signature (two parameters: PettingZoo; one: engine). ``goal_mode`` (``"window"``, default: the
``D x D`` goal window; or ``"cell"``) says what the actions mean. A TorchRL ``TensorDictModule`` that
reads ``CatmipEnv``'s keys is accepted too (:class:`~catmip_rl.adapters.torchrl_policy.TorchRLPolicy`).

A factory whose policy cannot play the world it is given (e.g. a CNN built for one map size) raises
:class:`catmip_env.play.WorldNotSupported`: ``catmip bench paper`` leaves the method out of that panel and
says so in the figure's summary.

Every way a policy can fail -- a missing file, no such factory, a wrong return type, a crash inside
``act``, an action its mask forbids -- raises :class:`PolicyError`, one line naming the policy and the
problem (``catmip`` prints it and exits with code 2, writing nothing).

This module finds and loads the factory and defines what an engine-level policy reads (its read-only
:class:`EngineView`); :mod:`~catmip_rl.evaluation.checked_policy` wraps what the factory returns.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import os
import re
import sys
import threading
import traceback
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from catmip_env.constants import TARGET_BIT
from catmip_env.engines.events import EventEngine

__all__ = [
    "POLICY_LEVELS",
    "ReadOnlyView",
    "PolicyError",
    "PolicySource",
    "parse_policy_source",
    "load_factory",
    "EngineView",
    "StateView",
    "engine_view",
    "view_arrays",
    "view_meta",
    "read_only",
    "known_target",
    "VIEW_STATE_FIELDS",
    "WITHHELD_STATE_FIELDS",
    "VIEW_ARRAYS",
    "no_exit",
    "describe_failure",
]

POLICY_LEVELS = ("pettingzoo", "engine")
_MODULE = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*")


class PolicyError(ValueError):
    """A user's policy could not be loaded or did something the protocol does not allow."""


class _ExitCalled(BaseException):
    """``os._exit(code)`` called by a policy while :func:`no_exit` guards it (the process goes on)."""

    def __init__(self, code: Any) -> None:
        super().__init__(code)
        self.code = code


@contextmanager
def no_exit() -> Iterator[None]:
    """While a policy's code runs in this process: ``os._exit`` (and ``posix._exit``) called from this
    thread raises instead of ending the process without a word (an ``os._exit(0)`` would end ``catmip``
    with exit code 0 and no results), so that it is reported as the policy's failure. Other threads
    exit as before, and so does a child the policy forked (``os.fork()``, then ``os._exit`` in the
    child: a double fork). A policy played in a worker process (:mod:`~catmip_rl.evaluation.sandbox`)
    needs no guard: its process's end is observed."""
    real, caller, pid = os._exit, threading.get_ident(), os.getpid()
    modules = [m for m in (os, sys.modules.get("posix"), sys.modules.get("nt")) if m is not None]

    def guarded(code: int) -> None:
        if threading.get_ident() != caller or os.getpid() != pid:
            real(code)
        raise _ExitCalled(code)

    for module in modules:
        module._exit = guarded
    try:
        yield
    finally:
        for module in modules:
            module._exit = real


def describe_failure(exc: BaseException) -> str:
    """The exception on one line, with where it was raised (the innermost frame: file, line, function)."""
    frames = traceback.extract_tb(exc.__traceback__)
    last = frames[-1] if frames else None
    where = f" (at {Path(last.filename).name}:{last.lineno} in {last.name})" if last else ""
    if isinstance(exc, SystemExit):
        return f"SystemExit({exc.code!r}): the policy called sys.exit() or exit(){where}"
    if isinstance(exc, _ExitCalled):
        return f"os._exit({exc.code!r}): the policy tried to end the process{where}"
    text = " ".join(str(exc).split())
    return (f"{type(exc).__name__}: {text}" if text else type(exc).__name__) + where


# -- where the factory is -------------------------------------------------------------------------------
@dataclass(frozen=True)
class PolicySource:
    """``py:FILE.py:FACTORY`` or ``py:package.module:FACTORY``, parsed (not yet imported)."""

    source: str  # a .py file path or a dotted module name
    factory: str

    @property
    def is_file(self) -> bool:
        return self.source.endswith(".py")

    def __str__(self) -> str:
        return f"py:{self.source}:{self.factory}"


def parse_policy_source(spec: str) -> PolicySource:
    """``"py:FILE.py:FACTORY"`` | ``"py:package.module:FACTORY"`` -> :class:`PolicySource`; a
    :class:`PolicyError` for a malformed spec or a file that is not there."""
    body = spec[len("py:") :] if spec.startswith("py:") else spec
    source, sep, factory = body.rpartition(":")
    if not sep or not source or not factory.isidentifier():
        raise PolicyError(
            f"policy {spec!r}: expected py:FILE.py:FACTORY or py:package.module:FACTORY "
            "(FACTORY a Python name)"
        )
    if source.endswith(".py"):
        path = Path(source).expanduser()
        if not path.is_file():
            raise PolicyError(f"policy {spec!r}: no such file {path}")
        return PolicySource(str(path.resolve()), factory)
    if _MODULE.fullmatch(source) is None:
        raise PolicyError(f"policy {spec!r}: {source!r} is neither a .py file nor a dotted module name")
    return PolicySource(source, factory)


def load_factory(src: PolicySource, name: str | None = None) -> Callable[..., Any]:
    """Import the file or module and return its factory; :class:`PolicyError` on any failure (the
    import's own error, named). A file is imported as ``python FILE`` would run it: its folder is put
    on ``sys.path`` first, so that it can import the modules beside it. ``name``: the method's name,
    for messages."""
    who = f"policy {name or src}"
    try:
        if src.is_file:
            path = Path(src.source)
            if str(path.parent) not in sys.path:
                sys.path.insert(0, str(path.parent))
            # a stable, unique module name per file, so that pickling and re-imports find the same module
            name = f"catmip_user_policy_{hashlib.sha1(str(path).encode()).hexdigest()[:12]}"
            module = sys.modules.get(name)
            if module is None:
                spec = importlib.util.spec_from_file_location(name, path)
                if spec is None or spec.loader is None:
                    raise ImportError(f"cannot import {path}")
                module = importlib.util.module_from_spec(spec)
                sys.modules[name] = module
                try:
                    with no_exit():
                        spec.loader.exec_module(module)
                except BaseException:
                    del sys.modules[name]
                    raise
        else:
            with no_exit():
                module = importlib.import_module(src.source)
    except KeyboardInterrupt:
        raise
    except BaseException as exc:  # SyntaxError, ImportError, SystemExit, anything the module runs
        raise PolicyError(f"{who}: importing {src.source} failed: {describe_failure(exc)}") from None
    factory = getattr(module, src.factory, None)
    if factory is None:
        names = sorted(n for n, v in vars(module).items() if callable(v) and not n.startswith("_"))
        shown = ", ".join(names[:8]) + (", ..." if len(names) > 8 else "")
        raise PolicyError(f"{who}: {src.source} has no {src.factory!r} (its callables: {shown or 'none'})")
    if not callable(factory):
        raise PolicyError(f"{who}: {src.factory} is a {type(factory).__name__}, not a callable factory")
    return factory


# -- what an engine-level policy reads: a read-only view -----------------------------------------------
VIEW_STATE_FIELDS = (
    "pos",
    "heading",
    "cls",
    "speed",
    "can_rescue",
    "belief",
    "comp",
    "goal",
    "ticks",
    "done",
    "comm_sigma",
    "heard_tick",
    "heard_pos",
    "heard_knows",
    "heard_goal",
)
"""The fields of the engine's ``state`` a policy reads (:class:`EngineView`), plus ``target`` as known."""
WITHHELD_STATE_FIELDS = (
    "grid",
    "rng",
    "used_occ",
    "moves",
    "collisions",
    "found_tick",
    "informed_tick",
    "rescue_tick",
    "pending_reward",
    "episode",
)
"""The fields withheld from policies: the true map, the world's random stream, the noise drawn, the
episode's counters and outcome (what it is scored on), and its episode index (with the map set's seed,
which a policy is not told either, it would name the map)."""
VIEW_ARRAYS = ("obs_global", "obs_local", "masks", "mstate", "active")
"""The engine's arrays a policy reads besides ``state``'s (``active`` computed at each event)."""
VIEW_DOC = "docs/benchmark-your-algorithm.md#what-a-policy-may-read"


def read_only(array: np.ndarray) -> np.ndarray:
    """``array``'s memory as a read-only array (no copy) whose flag cannot be set back: writing it raises
    ``ValueError: assignment destination is read-only``."""
    return np.asarray(memoryview(array).toreadonly())


def known_target(state: Any) -> np.ndarray:
    """(B, 2) the target's cell in the worlds where some robot's belief holds it (its ``TARGET_BIT``),
    (-1, -1) elsewhere: no more than the beliefs say (a rescuer knows the target by its own belief)."""
    b, n = state.pos.shape[:2]
    tr, tc = state.target[:, 0], state.target[:, 1]
    bits = state.belief[np.arange(b)[:, None], np.arange(n)[None, :], tr[:, None], tc[:, None]]
    known = ((bits & TARGET_BIT) != 0).any(axis=1)
    return np.where(known[:, None], state.target, -1).astype(np.int64)


def view_arrays(engine: EventEngine) -> dict[str, np.ndarray]:
    """The arrays of :class:`EngineView` of ``engine``'s current event, keyed by name (``state.`` for the
    state's): the engine's own memory read-only, ``active`` and ``state.target`` computed (copies)."""
    st = engine.state
    arrays = {name: read_only(getattr(engine, name)) for name in VIEW_ARRAYS}
    arrays |= {f"state.{name}": read_only(getattr(st, name)) for name in VIEW_STATE_FIELDS}
    arrays["state.target"] = read_only(known_target(st))
    arrays["world.keys"] = read_only(engine.world.world_keys)
    return arrays


def view_meta(engine: EventEngine) -> dict[str, Any]:
    """What :class:`EngineView` says of ``engine`` besides its arrays (fixed for the engine's life)."""
    return {
        "cfg": engine.cfg,
        "goal_mode": engine.goal_mode,
        "num_actions": engine.num_actions,
        "stay_action": engine.stay_action,
    }


class ReadOnlyView:
    """An object whose attributes are set once (by its class) and then refuse to be set or deleted."""

    __slots__ = ()
    _what = "the view"

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"{self._what} is read-only: a policy may not set {name!r} ({VIEW_DOC})")

    def __delattr__(self, name: str) -> None:
        raise AttributeError(f"{self._what} is read-only: a policy may not delete {name!r} ({VIEW_DOC})")


class StateView(ReadOnlyView):
    """``engine.state`` as a policy sees it: the fields of :data:`VIEW_STATE_FIELDS` read-only, ``target``
    as the robots know it (:func:`known_target`); ground truth (:data:`WITHHELD_STATE_FIELDS`) is not
    there."""

    __slots__ = ("_arrays",)
    _what = "engine.state"

    def __init__(self, arrays: dict[str, np.ndarray]) -> None:
        object.__setattr__(self, "_arrays", arrays)

    def __getattr__(self, name: str) -> Any:
        arrays = object.__getattribute__(self, "_arrays")
        if name in arrays:
            return arrays[name]
        if name in WITHHELD_STATE_FIELDS:
            raise AttributeError(
                f"engine.state.{name} is withheld from policies (ground truth or the episode's outcome); "
                f"a policy reads its robots' observations and beliefs ({VIEW_DOC})"
            )
        raise AttributeError(f"engine.state has no {name!r} ({VIEW_DOC})")

    def __dir__(self) -> list[str]:
        return sorted(object.__getattribute__(self, "_arrays"))


class _WorldView(ReadOnlyView):
    __slots__ = ("keys",)
    _what = "engine.world"

    def __init__(self, keys: np.ndarray) -> None:
        object.__setattr__(self, "keys", keys)

    def __getattr__(self, name: str) -> Any:
        raise AttributeError(
            f"engine.world.{name} is withheld from policies: of the world a policy reads only each "
            f"world's key (engine.world.keys, to key a random stream per world) ({VIEW_DOC})"
        )


class EngineView(ReadOnlyView):
    """What an engine-level policy's ``act(engine)`` is given: the
    :class:`~catmip_env.engines.events.EventEngine`'s observations at the current event, every array
    read-only (writing one raises), and nothing that steps, resets or edits the world. It has ``cfg``,
    ``num_worlds``, ``num_robots``, ``shape``, ``num_actions``, ``goal_mode``, ``stay_action``,
    ``obs_global``, ``obs_local``, ``masks``, ``active``, ``mstate``, ``world.keys`` (each world's key:
    :func:`~catmip_env.engines.world.world_key`, to key a random stream per world; neither the map set's
    seed nor the episode index), ``action_to_cell`` and a ``state`` (:class:`StateView`) without the
    ground truth (the true map; the target's cell only where a robot knows it).

    Built from arrays and plain values, not from an engine: the same view is built in the process that
    holds the engine (:func:`view_arrays`, no copy) and in a worker that holds none
    (:mod:`~catmip_rl.evaluation.sandbox`)."""

    __slots__ = (
        "cfg",
        "goal_mode",
        "num_actions",
        "stay_action",
        "num_worlds",
        "num_robots",
        "shape",
        "obs_global",
        "obs_local",
        "masks",
        "mstate",
        "active",
        "state",
        "world",
    )
    _what = "the engine a policy is given"

    def __init__(self, meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
        put = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731
        for key in ("cfg", "goal_mode", "num_actions", "stay_action"):
            put(key, meta[key])
        for key in VIEW_ARRAYS:
            put(key, arrays[key])
        b, n, *_ = arrays["masks"].shape
        put("num_worlds", b)
        put("num_robots", n)
        put("shape", tuple(arrays["state.belief"].shape[2:]))
        put("state", StateView({k[len("state.") :]: v for k, v in arrays.items() if k.startswith("state.")}))
        put("world", _WorldView(arrays["world.keys"]))

    action_to_cell = EventEngine.action_to_cell  # it reads goal_mode, shape, cfg, state.pos: all here

    def __getattr__(self, name: str) -> Any:  # only for names it does not have
        if name in ("step", "reset", "refresh", "seed"):
            raise AttributeError(f"a policy may not call engine.{name}(): the evaluator steps the world")
        raise AttributeError(f"the engine a policy is given has no {name!r} ({VIEW_DOC})")


def engine_view(engine: EventEngine) -> EngineView:
    """:class:`EngineView` of ``engine``'s current event (its memory, read-only: no copy)."""
    return EngineView(view_meta(engine), view_arrays(engine))
