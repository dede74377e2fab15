"""A user's policy as the evaluator plays it: the factory's answer wrapped, every call guarded (its
failures become :class:`~catmip_rl.evaluation.user_policy.PolicyError`), every answer checked against the
engine. The protocol itself: :mod:`catmip_rl.evaluation.user_policy`."""

from __future__ import annotations

import copy
import inspect
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from catmip_env.config import EnvConfig
from catmip_env.engines.events import GOAL_MODES, EventEngine
from catmip_env.envs.spaces import macro_infos, macro_observations, parse_actions
from catmip_env.play import WorldNotSupported
from catmip_rl.evaluation.user_policy import (
    POLICY_LEVELS,
    VIEW_DOC,
    PolicyError,
    describe_failure,
    engine_view,
    no_exit,
)

__all__ = [
    "make_user_policy",
    "wrap_user_policy",
    "WrappedUserPolicy",
    "CheckedEnginePolicy",
    "PettingZooPolicy",
    "pettingzoo_inputs",
    "policy_failure",
]


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
        raise PolicyError(f"policy {name}: the factory raised {describe_failure(exc)}") from None
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
        wrapped = PettingZooPolicy(act, name, goal_mode, reset if callable(reset) else None, user=policy)
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
    described = describe_failure(exc)
    if (
        isinstance(exc, ValueError)
        and "read-only" in str(exc)
        or isinstance(exc, AttributeError)
        and ("read-only" in str(exc) or "withheld" in str(exc))
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

    def calls(self) -> dict[str, int] | None:
        """The project's entry points the policy has called (worlds built, map sets read, planners run:
        :mod:`~catmip_rl.evaluation.call_counts`), counted where it plays isolated; None in-process."""
        return None

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
                f"policy {self.name}: act(engine) returned {type(out).__name__} ({describe_failure(exc)})"
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
    engine, episode after episode, calling :meth:`reset` before each.

    Given the ``user``'s object, every episode is played by a copy of it as its factory made it
    (``copy.deepcopy``, taken at :meth:`reset`): a map's episode never depends on the maps played before
    it, so any map replays alone (what a leaderboard's check plays), whatever stream the policy draws
    from. Its ``episode_columns()`` are each copy's, in the order played."""

    one_world_at_a_time = True

    def __init__(
        self,
        act: Callable[[dict, dict], Any],
        name: str,
        goal_mode: str = "window",
        reset: Callable[[], Any] | None = None,
        user: Any = None,
    ) -> None:
        self._act, self._reset, self.name, self.goal_mode = act, reset, name, goal_mode
        self._last_tick: np.ndarray | None = None
        self._user = self._pristine = None
        self._columns: list[Any] = []
        if user is not None:
            self._pristine = self._copy(user)

    def _copy(self, user: Any) -> Any:
        try:
            with no_exit():
                return copy.deepcopy(user)
        except KeyboardInterrupt:
            raise
        except BaseException as exc:
            raise PolicyError(
                f"policy {self.name}: its object cannot be copied ({describe_failure(exc)}): a "
                "PettingZoo-level policy plays every map from the state its factory made, a copy of it "
                "(copy.deepcopy)"
            ) from None

    def reset(self) -> None:
        """Start of an episode: a fresh copy of the factory's policy (with a ``user``), then the policy's
        own ``reset()``, if it has one."""
        if self._pristine is not None:
            self._keep_columns()
            self._user = self._copy(self._pristine)
            self._act = getattr(self._user, "act", self._user)
            reset = getattr(self._user, "reset", None)
            self._reset = reset if callable(reset) else None
        if self._reset is not None:
            self._call(self._reset, "reset()")

    def _keep_columns(self) -> None:
        """The columns of the copy that played the last episode, kept before it is replaced."""
        if self._user is not None and callable(getattr(self._user, "episode_columns", None)):
            self._columns.append(self._call(self._user.episode_columns, "episode_columns()"))

    def forward_hooks(self, policy: Any) -> None:
        super().forward_hooks(policy)
        if self._pristine is not None and hasattr(self, "episode_columns"):
            self.episode_columns = self._all_columns

    def _all_columns(self) -> Any:
        """Every copy's ``episode_columns()``, joined in the order the episodes were played."""
        self._keep_columns()
        self._user = None
        parts, self._columns = self._columns, []
        if not parts or any(not isinstance(p, Mapping) for p in parts):
            return next((p for p in parts if not isinstance(p, Mapping)), {})
        names = list(parts[0])
        if any(list(p) != names for p in parts):
            raise PolicyError(f"policy {self.name}: episode_columns() named other columns in another episode")
        return {k: np.concatenate([np.asarray(p[k]).reshape(-1) for p in parts]) for k in names}

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
            event_ticks = tick - int(self._last_tick[b])
            self._last_tick[b] = tick
            actions = self.ask(engine, int(b), agents, event_ticks)
            if not isinstance(actions, Mapping):
                raise PolicyError(
                    f"policy {self.name}: act(observations, infos) returned {type(actions).__name__}, "
                    "expected a dict {robot: action}"
                )
            row = np.zeros(engine.num_robots, np.int64)
            try:
                parse_actions(
                    actions,
                    agents,
                    _robot_index(agents),
                    engine.active[b],
                    self.goal_mode,
                    engine.num_actions,
                    True,
                    row,
                )
            except ValueError as exc:
                where = f"world {b} at tick {int(st.ticks[b])}"
                raise PolicyError(f"policy {self.name}: {' '.join(str(exc).split())} ({where})") from None
            active = engine.active[b]
            out[b, active] = row[active]
            _check_allowed(out, engine, np.array([b]), self.name)
        return out

    def ask(self, engine: EventEngine, b: int, agents: list[str], event_ticks: int) -> Any:
        """The policy's answer for world ``b`` (its ``act`` on :func:`pettingzoo_inputs`)."""
        obs, infos = pettingzoo_inputs(engine, b, agents, event_ticks)
        return self._call(self._act, "act(observations, infos)", obs, infos)


def pettingzoo_inputs(engine: Any, b: int, agents: list[str], event_ticks: int) -> tuple[dict, dict]:
    """World ``b``'s ``(observations, infos)`` as ``search_rescue_v0`` gives them (the same functions), in
    strict mode (an invalid action is an error, never replaced: the counters are 0). ``engine``: an
    :class:`EventEngine`, or what a sandbox worker builds of one world's arrays."""
    obs, _ = macro_observations(engine, b, agents)
    infos = macro_infos(engine, b, agents, event_ticks)
    for info in infos.values():
        info["invalid_action"] = info["invalid_actions"] = 0
    return obs, infos


def _robot_index(agents: list[str]) -> Callable[[str], int]:
    index = {a: i for i, a in enumerate(agents)}

    def lookup(agent: str) -> int:
        try:
            return index[agent]
        except (KeyError, TypeError):
            raise ValueError(f"unknown robot id {agent!r}; robots are {agents}") from None

    return lookup
