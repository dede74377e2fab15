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
  :class:`~catmip_env.events.EventEngine` (the :class:`catmip_env.play.Policy` protocol, what the
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
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import inspect
import os
import re
import sys
import threading
import traceback
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from catmip_env.config import EnvConfig
from catmip_env.constants import TARGET_BIT
from catmip_env.events import GOAL_MODES, EventEngine
from catmip_env.play import WorldNotSupported
from catmip_env.spaces import macro_infos, macro_observations, parse_actions

__all__ = [
    "POLICY_LEVELS", "PolicyError", "PolicySource", "parse_policy_source", "load_factory", "make_user_policy",
    "wrap_user_policy", "WrappedUserPolicy", "CheckedEnginePolicy", "PettingZooPolicy", "EngineView",
    "StateView", "engine_view", "view_arrays", "view_meta", "read_only", "known_target", "VIEW_STATE_FIELDS",
    "WITHHELD_STATE_FIELDS", "VIEW_ARRAYS", "no_exit", "policy_failure",
]  # fmt: skip

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
    exit as before. A policy played in a worker process (:mod:`~catmip_rl.evaluation.sandbox`) needs no
    guard: its process's end is observed."""
    real, caller = os._exit, threading.get_ident()
    modules = [m for m in (os, sys.modules.get("posix"), sys.modules.get("nt")) if m is not None]

    def guarded(code: int) -> None:
        if threading.get_ident() != caller:
            real(code)
        raise _ExitCalled(code)

    for module in modules:
        module._exit = guarded
    try:
        yield
    finally:
        for module in modules:
            module._exit = real


def _describe(exc: BaseException) -> str:
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
        raise PolicyError(f"{who}: importing {src.source} failed: {_describe(exc)}") from None
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
    "pos", "heading", "cls", "speed", "can_rescue", "belief", "comp", "goal", "ticks", "done", "episode",
    "comm_sigma", "heard_tick", "heard_pos", "heard_knows", "heard_goal",
)  # fmt: skip
"""The fields of the engine's ``state`` a policy reads (:class:`EngineView`), plus ``target`` as known."""
WITHHELD_STATE_FIELDS = (
    "grid", "rng", "used_occ", "moves", "collisions", "found_tick", "informed_tick", "rescue_tick",
    "pending_reward",
)  # fmt: skip
"""The fields withheld from policies: the true map, the world's random stream, the noise drawn, and the
episode's counters and outcome (what it is scored on)."""
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
    return arrays


def view_meta(engine: EventEngine) -> dict[str, Any]:
    """What :class:`EngineView` says of ``engine`` besides its arrays (fixed for the engine's life)."""
    return {"cfg": engine.cfg, "goal_mode": engine.goal_mode, "num_actions": engine.num_actions,
            "stay_action": engine.stay_action, "base_seed": int(engine.world.base_seed)}  # fmt: skip


class _Frozen:
    """An object whose attributes are set once (by its class) and then refuse to be set or deleted."""

    __slots__ = ()
    _what = "the view"

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"{self._what} is read-only: a policy may not set {name!r} ({VIEW_DOC})")

    def __delattr__(self, name: str) -> None:
        raise AttributeError(f"{self._what} is read-only: a policy may not delete {name!r} ({VIEW_DOC})")


class StateView(_Frozen):
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


class _WorldView(_Frozen):
    __slots__ = ("base_seed",)
    _what = "engine.world"

    def __init__(self, base_seed: int) -> None:
        object.__setattr__(self, "base_seed", base_seed)

    def __getattr__(self, name: str) -> Any:
        raise AttributeError(
            f"engine.world.{name} is withheld from policies: of the world a policy reads only its seed "
            f"(engine.world.base_seed) ({VIEW_DOC})"
        )


class EngineView(_Frozen):
    """What an engine-level policy's ``act(engine)`` is given: the :class:`~catmip_env.events.EventEngine`'s
    observations at the current event, every array read-only (writing one raises), and nothing that
    steps, resets or edits the world. It has ``cfg``, ``num_worlds``, ``num_robots``, ``shape``,
    ``num_actions``, ``goal_mode``, ``stay_action``, ``obs_global``, ``obs_local``, ``masks``, ``active``,
    ``mstate``, ``world.base_seed``, ``action_to_cell`` and a ``state`` (:class:`StateView`) without the
    ground truth (the true map; the target's cell only where a robot knows it).

    Built from arrays and plain values, not from an engine: the same view is built in the process that
    holds the engine (:func:`view_arrays`, no copy) and in a worker that holds none
    (:mod:`~catmip_rl.evaluation.sandbox`)."""

    __slots__ = ("cfg", "goal_mode", "num_actions", "stay_action", "num_worlds", "num_robots", "shape",
                 "obs_global", "obs_local", "masks", "mstate", "active", "state", "world")  # fmt: skip
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
        put("world", _WorldView(meta["base_seed"]))

    def action_to_cell(self, b: int, i: int, action: int) -> tuple[int, int]:
        """Goal cell of robot i of world b for ``action`` (no validity check), as the engine's."""
        if self.goal_mode == "cell":
            return divmod(int(action), self.shape[1])
        d = self.cfg.window
        r, c = self.state.pos[b, i]
        return int(r + action // d - d // 2), int(c + action % d - d // 2)

    def __getattr__(self, name: str) -> Any:  # only for names it does not have
        if name in ("step", "reset", "refresh", "seed"):
            raise AttributeError(f"a policy may not call engine.{name}(): the evaluator steps the world")
        raise AttributeError(f"the engine a policy is given has no {name!r} ({VIEW_DOC})")


def engine_view(engine: EventEngine) -> EngineView:
    """:class:`EngineView` of ``engine``'s current event (its memory, read-only: no copy)."""
    return EngineView(view_meta(engine), view_arrays(engine))


# -- what the factory returns ---------------------------------------------------------------------------
def _act_level(act: Callable, name: str) -> str:
    try:
        params = inspect.signature(act).parameters.values()
    except (TypeError, ValueError):
        raise PolicyError(f"policy {name}: cannot read act()'s signature; set policy.level") from None
    required = [
        p for p in params if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD) and p.default is p.empty
    ]
    if len(required) == 2:
        return "pettingzoo"
    if len(required) == 1:
        return "engine"
    raise PolicyError(
        f"policy {name}: act() takes {len(required)} required arguments; write act(observations, infos) "
        "(PettingZoo level) or act(engine) (engine level), or set policy.level"
    )


def make_user_policy(
    factory: Callable[..., Any], env_config: EnvConfig, seed: int, name: str
) -> CheckedEnginePolicy | PettingZooPolicy:
    """Call ``factory(env_config, seed)`` and wrap what it returns for the evaluator: a
    :class:`PettingZooPolicy` or a :class:`CheckedEnginePolicy` (a TorchRL module through
    :class:`~catmip_rl.adapters.torchrl_policy.TorchRLPolicy`)."""
    try:
        with no_exit():
            policy = factory(env_config, seed)
    except KeyboardInterrupt:
        raise
    except WorldNotSupported as exc:  # a policy for other worlds: bench paper leaves this panel out
        raise WorldNotSupported(f"policy {name} cannot play this world: {exc}") from None
    except BaseException as exc:  # SystemExit, GeneratorExit, os._exit: the policy's failure, not ours
        raise PolicyError(f"policy {name}: the factory raised {_describe(exc)}") from None
    return wrap_user_policy(policy, name)


def wrap_user_policy(policy: Any, name: str) -> CheckedEnginePolicy | PettingZooPolicy:
    """A user's policy object (a factory's answer) wrapped for the evaluator, its optional members of
    :class:`catmip_env.play.Policy` forwarded (their failures too become :class:`PolicyError`)."""
    if "tensordict" in sys.modules:  # a TorchRL module can only come from a process that imported it
        from catmip_rl.adapters.torchrl_policy import TorchRLPolicy

        if TorchRLPolicy.wraps(policy):
            policy = TorchRLPolicy(policy)
    act = getattr(policy, "act", None)
    if act is None:
        if policy is None or not callable(policy):
            raise PolicyError(
                f"policy {name}: the factory returned {type(policy).__name__}, not a policy: return an "
                "object with act(observations, infos) (PettingZoo level) or act(engine) (engine level)"
            )
        act = policy  # a plain function is its own act
    level = getattr(policy, "level", None)
    if level is None:
        level = _act_level(act, name)
    if level not in POLICY_LEVELS:
        raise PolicyError(f"policy {name}: level {level!r} is not one of {list(POLICY_LEVELS)}")
    goal_mode = getattr(policy, "goal_mode", "window")
    if goal_mode not in GOAL_MODES:
        raise PolicyError(f"policy {name}: goal_mode {goal_mode!r} is not one of {list(GOAL_MODES)}")
    reset = getattr(policy, "reset", None)
    if level == "engine":
        wrapped = CheckedEnginePolicy(act, name, goal_mode)
    else:
        wrapped = PettingZooPolicy(act, name, goal_mode, reset if callable(reset) else None)
    wrapped.forward_hooks(policy)
    return wrapped


def _check_allowed(actions: np.ndarray, engine: EventEngine, worlds: np.ndarray, name: str) -> None:
    """PolicyError naming the first active robot of ``worlds`` whose action is out of range or masked
    (one vectorised check: it runs at every event of every world)."""
    a = engine.num_actions
    acts = actions[worlds]  # (W, N)
    in_range = (acts >= 0) & (acts < a)
    allowed = np.take_along_axis(engine.masks[worlds], np.clip(acts, 0, a - 1)[..., None], -1)[..., 0] != 0
    bad = engine.active[worlds] & ~(in_range & allowed)
    if not bad.any():
        return
    w, i = (int(x[0]) for x in np.nonzero(bad))
    b, act = int(worlds[w]), int(acts[w, i])
    why = f"out of range (actions are 0..{a - 1})" if not in_range[w, i] else "forbidden by its action mask"
    raise PolicyError(
        f"policy {name}: action {act} of robot_{i} in world {b} at tick {int(engine.state.ticks[b])} is "
        f"{why}; choose among the actions whose mask entry is 1"
    )


def policy_failure(name: str, what: str, exc: BaseException) -> str:
    """The one line of a policy's call ``what`` that raised ``exc`` (a write to the read-only view said
    as such)."""
    described = _describe(exc)
    if isinstance(exc, ValueError) and "read-only" in str(exc) or isinstance(exc, AttributeError) and (
        "read-only" in str(exc) or "withheld" in str(exc)
    ):
        return (
            f"policy {name}: {what} tried to change or read what a policy may not ({described}): a policy "
            f"reads its observations and never writes the world it is scored in ({VIEW_DOC})"
        )
    return f"policy {name}: {what} raised {described}"


class WrappedUserPolicy:
    """What both wrappers share: the policy's name, calls whose failures become :class:`PolicyError`,
    and the optional members of :class:`catmip_env.play.Policy` taken from the user's object."""

    name: str

    def _call(self, fn: Callable, what: str, *args):
        try:
            with no_exit():
                return fn(*args)
        except KeyboardInterrupt:
            raise
        except PolicyError:
            raise
        except BaseException as exc:  # sys.exit(), GeneratorExit, os._exit: its failure, not ours
            raise PolicyError(policy_failure(self.name, what, exc)) from None

    def forward_hooks(self, policy: Any) -> None:
        """Expose the optional members ``policy`` has (and only those: the evaluator asks by name)."""
        if isinstance(getattr(policy, "deterministic", None), bool):  # argmax or sampled, on the summary
            self.deterministic = policy.deterministic
        files = getattr(policy, "files", None)
        if files is not None:  # the files its answers depend on: hashed on the summary
            self.files = self._files(files)
        if callable(getattr(policy, "start_episodes", None)):
            what = "start_episodes(num_worlds, num_robots)"
            self.start_episodes = lambda b, n: self._call(policy.start_episodes, what, b, n)
        if callable(getattr(policy, "episode_columns", None)):
            self.episode_columns = lambda: self._call(policy.episode_columns, "episode_columns()")
        if callable(getattr(policy, "sampled", None)):
            self.sampled = lambda seed: wrap_user_policy(
                self._call(policy.sampled, "sampled(seed)", seed), self.name
            )

    def _files(self, files: Any) -> tuple[str, ...]:
        """The policy's ``files`` as paths of existing files; PolicyError naming what is not one."""
        if isinstance(files, (str, Path)) or not isinstance(files, (list, tuple)):
            raise PolicyError(f"policy {self.name}: files must be a list of paths, got {files!r}")
        for f in files:
            if not isinstance(f, (str, Path)) or not Path(f).expanduser().is_file():
                raise PolicyError(f"policy {self.name}: files names {f!r}, which is not a file")
        return tuple(str(Path(f).expanduser()) for f in files)


class CheckedEnginePolicy(WrappedUserPolicy):
    """An engine-level policy whose every answer is checked: shape (B, N), integers, allowed for the
    active robots of live worlds; crashes and bad answers become :class:`PolicyError`."""

    def __init__(self, act: Callable[[EventEngine], Any], name: str, goal_mode: str = "window") -> None:
        self._act, self.name, self.goal_mode = act, name, goal_mode

    def act(self, engine: EventEngine) -> np.ndarray:
        """The policy's answer for ``engine``'s current event: ``act`` is given a read-only
        :class:`EngineView` (never the engine), and its answer is checked against the engine."""
        out = self._call(self._act, "act(engine)", engine_view(engine))
        return self.checked(out, engine)

    def checked(self, out: Any, engine: EventEngine) -> np.ndarray:
        """``out`` (what ``act`` returned) as (B, N) int64 actions, or PolicyError saying what is wrong."""
        try:
            actions = np.asarray(out)
        except Exception as exc:
            raise PolicyError(
                f"policy {self.name}: act(engine) returned {type(out).__name__} ({_describe(exc)})"
            ) from None
        want = (engine.num_worlds, engine.num_robots)
        if actions.shape != want:
            raise PolicyError(
                f"policy {self.name}: act(engine) returned shape {actions.shape}, expected {want}"
            )
        if actions.dtype.kind not in "iu":
            raise PolicyError(
                f"policy {self.name}: act(engine) returned {actions.dtype} actions, expected integers"
            )
        actions = actions.astype(np.int64)
        _check_allowed(actions, engine, np.flatnonzero(~engine.state.done), self.name)
        return actions


class PettingZooPolicy(WrappedUserPolicy):
    """A PettingZoo-level policy as an engine-level one: for every live world with an active robot it
    builds that world's ``(observations, infos)`` as ``search_rescue_v0`` does (the same functions) and
    calls ``act``; busy robots keep their goals. The evaluator plays such a policy on a one-world
    engine, episode after episode, calling :meth:`reset` before each."""

    one_world_at_a_time = True

    def __init__(
        self,
        act: Callable[[dict, dict], Any],
        name: str,
        goal_mode: str = "window",
        reset: Callable[[], Any] | None = None,
    ) -> None:
        self._act, self._reset, self.name, self.goal_mode = act, reset, name, goal_mode
        self._last_tick: np.ndarray | None = None

    def reset(self) -> None:
        """Start of an episode: the policy's own ``reset()``, if it has one."""
        if self._reset is not None:
            self._call(self._reset, "reset()")

    def act(self, engine: EventEngine) -> np.ndarray:
        st = engine.state
        agents = [f"robot_{i}" for i in range(engine.num_robots)]
        if self._last_tick is None or len(self._last_tick) != engine.num_worlds:
            self._last_tick = np.zeros(engine.num_worlds, np.int64)
        out = engine.masks.argmax(-1).astype(np.int64)  # busy robots: their one allowed action, "keep"
        for b in np.flatnonzero(~st.done & engine.active.any(-1)):
            tick = int(st.ticks[b])
            if tick < self._last_tick[b]:  # a new episode in this world
                self._last_tick[b] = 0
            obs, _ = macro_observations(engine, int(b), agents)
            infos = macro_infos(engine, int(b), agents, tick - int(self._last_tick[b]))
            for info in infos.values():  # strict mode: an invalid action is an error, never replaced
                info["invalid_action"] = info["invalid_actions"] = 0
            self._last_tick[b] = tick
            actions = self._call(self._act, "act(observations, infos)", obs, infos)
            if not isinstance(actions, Mapping):
                raise PolicyError(
                    f"policy {self.name}: act(observations, infos) returned {type(actions).__name__}, "
                    "expected a dict {robot: action}"
                )
            row = np.zeros(engine.num_robots, np.int64)
            try:
                parse_actions(
                    actions, agents, _robot_index(agents), engine.active[b], self.goal_mode,
                    engine.num_actions, True, row,
                )  # fmt: skip
            except ValueError as exc:
                where = f"world {b} at tick {int(st.ticks[b])}"
                raise PolicyError(f"policy {self.name}: {' '.join(str(exc).split())} ({where})") from None
            active = engine.active[b]
            out[b, active] = row[active]
            _check_allowed(out, engine, np.array([b]), self.name)
        return out


def _robot_index(agents: list[str]) -> Callable[[str], int]:
    index = {a: i for i, a in enumerate(agents)}

    def lookup(agent: str) -> int:
        try:
            return index[agent]
        except (KeyError, TypeError):
            raise ValueError(f"unknown robot id {agent!r}; robots are {agents}") from None

    return lookup
