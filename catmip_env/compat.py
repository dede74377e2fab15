"""Old module paths, kept importable after the package was reorganised.

``install_aliases({"pkg.old": "pkg.new"})`` makes ``import pkg.old`` (and ``from pkg.old import X``)
work with a ``DeprecationWarning``: the old name is a thin module whose attributes are read from the
new one, or from the first of several (``"pkg.old": ("pkg.new", "pkg.other")``) that has them, for a
module whose contents went to several places.  Used by ``catmip_env`` and ``catmip_rl`` for the modules
they moved.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import types
import warnings

# catmip_env modules that were renamed: old path -> new path (or paths, searched in order)
ENV_MOVES = {
    "catmip_env.types": "catmip_env.constants",
    "catmip_env.engine": ("catmip_env.world", "catmip_env.dynamics", "catmip_env.sensing"),
    "catmip_env.planner": "catmip_env.paths",
    "catmip_env.baselines": "catmip_env.planners",
}


class _Aliases(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    def __init__(self) -> None:
        self.table: dict[str, tuple[str, ...]] = {}

    def find_spec(self, name, path=None, target=None):
        if name not in self.table:
            return None
        return importlib.machinery.ModuleSpec(name, self)

    def create_module(self, spec):
        return None  # a fresh, empty module

    def exec_module(self, module: types.ModuleType) -> None:
        new = self.table[module.__name__]
        where = " / ".join(new)
        warnings.warn(
            f"{module.__name__} moved to {where}; import it from there", DeprecationWarning, stacklevel=2
        )
        targets = [importlib.import_module(name) for name in new]
        module.__doc__ = f"Moved to {where}."

        def attribute(name: str):  # PEP 562: the first new module that has it
            for target in targets:
                if hasattr(target, name):
                    return getattr(target, name)
            raise AttributeError(f"module {module.__name__!r} (moved to {where}) has no attribute {name!r}")

        module.__getattr__ = attribute
        module.__dir__ = lambda: sorted({n for t in targets for n in dir(t)})


_FINDER = _Aliases()


def install_aliases(table: dict[str, str | tuple[str, ...]]) -> None:
    """Make every old module path in ``table`` import its new module(s) (idempotent)."""
    _FINDER.table.update({old: (new,) if isinstance(new, str) else tuple(new) for old, new in table.items()})
    if _FINDER not in sys.meta_path:
        sys.meta_path.append(_FINDER)
