"""Counting the project's own entry points a ``py:`` policy calls while it plays, in the sandbox's worker
(:mod:`~catmip_rl.evaluation.workers`): whether it builds worlds, reads map sets, generates maps or runs
the project's planners. Installed before the factory is imported, so the counts cover the factory call
and every request after it; the parent reads them with ``policy.calls()``.

=====================  ==================================================================================
key                    calls counted (one per outermost call: a call made inside another of its own
                       kind counts once, e.g. ``EventEngine.__init__`` building its ``BatchedWorld``)
=====================  ==================================================================================
``worlds``             ``BatchedWorld.__init__`` / ``.reset``, ``EventEngine.__init__`` / ``.reset`` (the
                       PettingZoo and TorchRL envs, and the rollout planner's simulations, build these)
``map_sets``           ``catmip_env.maps.map_sets.manifest`` / ``map_hashes`` / ``check_maps``
``mapgen``             ``catmip_env.kernels.mapgen.generate`` (a map) and ``catmip_env.kernels.episodes.
                       load_episodes`` (a reset's worlds: one call per reset and thread)
``planners_made``      ``Planner.__init__`` (every planner: subclasses call it)
``planner_decisions``  ``act`` of ``Planner``, of every class in its subclasses' MROs that defines its own
                       (the relay rule, the rollout planner) and of ``WindowPlanner``
``restored``           wrappers found removed or bypassed (a module reloaded) and put back
=====================  ==================================================================================

What it catches: every call through the classes (patched in place, so references taken before are
covered) and through the module functions, also names imported from them before the wrappers were
installed (each module's alias is replaced). The originals live only in the wrappers' closures, not as
attributes, and before each request the worker checks every wrapper is still in place (a class or
function put back, or a module reloaded, is wrapped again and counted in ``restored``).

What it does not: a policy runs in the same process, so a determined one can escape -- calling an
original it digs out of a closure, copying the source, running the numba kernels directly, or editing
the counts it finds through the garbage collector. ``sys.setprofile`` would not close that (one
``sys.setprofile(None)`` removes it) and would call a Python function on every call the policy makes,
slowing a PettingZoo-level policy severalfold: it is not used. The counts are evidence of honest
use, not a proof against a hostile policy.
"""

from __future__ import annotations

import importlib
import inspect
import sys
import threading
from collections.abc import Callable
from typing import Any

__all__ = ["KINDS", "install_counters"]

KINDS = ("worlds", "map_sets", "mapgen", "planners_made", "planner_decisions")
_METHODS = (  # (module, class, method, kind)
    ("catmip_env.engines.world", "BatchedWorld", "__init__", "worlds"),
    ("catmip_env.engines.world", "BatchedWorld", "reset", "worlds"),
    ("catmip_env.engines.events", "EventEngine", "__init__", "worlds"),
    ("catmip_env.engines.events", "EventEngine", "reset", "worlds"),
    ("catmip_env.planners.core", "Planner", "__init__", "planners_made"),
    ("catmip_env.planners.window", "WindowPlanner", "act", "planner_decisions"),
)
_FUNCTIONS = (  # (module, function, kind)
    ("catmip_env.maps.map_sets", "manifest", "map_sets"),
    ("catmip_env.maps.map_sets", "map_hashes", "map_sets"),
    ("catmip_env.maps.map_sets", "check_maps", "map_sets"),
    ("catmip_env.kernels.mapgen", "generate", "mapgen"),
    ("catmip_env.kernels.episodes", "load_episodes", "mapgen"),
)
_PLANNER_MODULES = ("catmip_env.planners.baselines", "catmip_env.planners.rollout")


def _planner_acts() -> list[tuple[str, str, str, str]]:
    """(module, class, "act", kind) for every class that defines ``act`` in the MRO of ``Planner`` and
    its subclasses."""
    for name in _PLANNER_MODULES:
        importlib.import_module(name)
    base = importlib.import_module("catmip_env.planners.core").Planner
    classes, todo = {base}, [base]
    while todo:
        for sub in todo.pop().__subclasses__():
            if sub not in classes:
                classes.add(sub)
                todo.append(sub)
    found = {
        (k.__module__, k.__qualname__)
        for c in classes
        for k in c.__mro__
        if "act" in vars(k) and "." not in k.__qualname__
    }
    return [(m, q, "act", "planner_decisions") for m, q in sorted(found)]


def _aliases(module: str, name: str, kind: str) -> list[tuple[str, None, str, str]]:
    """The module function's place and every other module's name for it (imported before the wrappers)."""
    original = getattr(importlib.import_module(module), name)
    found = [(module, None, name, kind)]
    for alias, mod in list(sys.modules.items()):
        for attr, value in list(getattr(mod, "__dict__", {}).items()):
            if value is original and (alias, attr) != (module, name):
                found.append((alias, None, attr, kind))
    return found


class _Counters:
    """The wrappers (the originals only in their closures), their places and the counts."""

    def __init__(self) -> None:
        self.counts = dict.fromkeys((*KINDS, "restored"), 0)
        self.depth = threading.local()
        self.ours: dict[int, Callable] = {}  # id(wrapper) -> wrapper (kept alive, so ids stay unique)
        self.places: list[tuple[str, str | None, str, str]] = [*_METHODS, *_planner_acts()]
        for module, name, kind in _FUNCTIONS:
            self.places += _aliases(module, name, kind)
        self.installed: list[tuple[str, Any, str | None, Any, str, Callable]] = []

    def counting(self, fn: Callable, kind: str) -> Callable:
        counts, depth = self.counts, self.depth

        def wrapper(*args: Any, **kwargs: Any) -> Any:
            level = getattr(depth, kind, 0)
            if level == 0:
                counts[kind] += 1
            setattr(depth, kind, level + 1)
            try:
                return fn(*args, **kwargs)
            finally:
                setattr(depth, kind, level)

        for attr in ("__module__", "__name__", "__qualname__", "__doc__"):
            setattr(wrapper, attr, getattr(fn, attr, None))
        try:  # what the evaluator reads of an act (its arguments), without __wrapped__ (the original)
            wrapper.__signature__ = inspect.signature(fn)
        except (TypeError, ValueError):
            pass
        self.ours[id(wrapper)] = wrapper
        return wrapper

    def check(self, first: bool = False) -> None:
        """Put a wrapper wherever one is missing (all of them the first time). Fast while nothing moved:
        each wrapper, its owner and its module are where they were put."""
        if not first and all(
            sys.modules.get(module) is mod
            and (cls is None or getattr(mod, cls, None) is owner)
            and getattr(owner, attr, None) is wrapper
            for module, mod, cls, owner, attr, wrapper in self.installed
        ):
            return
        self.installed = []
        for module, cls, attr, kind in self.places:
            mod = sys.modules.get(module) or importlib.import_module(module)
            owner = mod if cls is None else getattr(mod, cls, None)
            current = None if owner is None else vars(owner).get(attr) if cls else getattr(owner, attr, None)
            if current is None:
                continue
            if self.ours.get(id(current)) is not current:
                current = self.counting(current, kind)
                setattr(owner, attr, current)
                self.counts["restored"] += 0 if first else 1
            self.installed.append((module, mod, cls, owner, attr, current))


def install_counters() -> Callable[[], dict[str, int]]:
    """Wrap the entry points of the module docstring (importing their modules) and return ``calls()``:
    it checks the wrappers (putting back any that is gone) and returns the counts so far,
    ``{"worlds": n, "map_sets": n, "mapgen": n, "planners_made": n, "planner_decisions": n,
    "restored": n}``; ``calls.check()`` checks without counting (the worker, before each request)."""
    counters = _Counters()
    counters.check(first=True)

    def calls() -> dict[str, int]:
        counters.check()
        return dict(counters.counts)

    calls.check = counters.check  # type: ignore[attr-defined]
    return calls
