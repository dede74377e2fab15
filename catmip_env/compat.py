"""Old module paths, kept importable after the package was reorganised.

``install_aliases({"pkg.old": "pkg.new"})`` makes ``import pkg.old`` (and ``from pkg.old import X``)
work with a ``DeprecationWarning``: the old name is a thin module whose attributes are read from the
new one.  Used by ``catmip_env`` and ``catmip_rl`` for the modules they moved.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import types
import warnings

# catmip_env modules that were renamed: old path -> new path
ENV_MOVES = {
    "catmip_env.types": "catmip_env.constants",
    "catmip_env.engine": "catmip_env.world",
    "catmip_env.planner": "catmip_env.paths",
    "catmip_env.baselines": "catmip_env.planners",
}


class _Aliases(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    def __init__(self) -> None:
        self.table: dict[str, str] = {}

    def find_spec(self, name, path=None, target=None):
        if name not in self.table:
            return None
        return importlib.machinery.ModuleSpec(name, self)

    def create_module(self, spec):
        return None  # a fresh, empty module

    def exec_module(self, module: types.ModuleType) -> None:
        new = self.table[module.__name__]
        warnings.warn(
            f"{module.__name__} moved to {new}; import it from there", DeprecationWarning, stacklevel=2
        )
        target = importlib.import_module(new)
        module.__doc__ = f"Moved to :mod:`{new}`."
        module.__getattr__ = lambda name: getattr(target, name)  # PEP 562
        module.__dir__ = lambda: dir(target)


_FINDER = _Aliases()


def install_aliases(table: dict[str, str]) -> None:
    """Make every old module path in ``table`` import its new module (idempotent)."""
    _FINDER.table.update(table)
    if _FINDER not in sys.meta_path:
        sys.meta_path.append(_FINDER)
