"""The structure tests/test_architecture.py checks and docs/figures/architecture.py draws: every module
of catmip_env and catmip_rl, the group (layer) it belongs to, and the import graph between them (lazy
imports included, marked)."""

from __future__ import annotations

import ast
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("catmip_env", "catmip_rl")

# Every folder of the two packages is a group of its own (catmip_env/engines/, catmip_env/kernels/,
# catmip_rl/amat/, catmip_rl/store/, ...). catmip_env's flat modules are its base (they import no folder of
# the package), its face (no module of the package imports them: __init__, the demo) or a group of their
# own between the folders (play, the episode loop); catmip_rl's flat modules are its face (__init__ and a
# path kept for 1.0 code), imported by none.


def modules(root: Path = ROOT) -> dict[str, Path]:
    """Dotted module name -> file, for every module of the two packages."""
    out = {}
    for pkg in PACKAGES:
        for path in sorted((root / pkg).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            out[".".join(parts)] = path
    return out


def group(module: str) -> str:
    """The box a module is drawn in: its folder, or for a flat module of catmip_env ``env: base`` or
    ``env: face`` (whether it imports a module of one of the package's folders)."""
    pkg, *rest = module.split(".")
    short = "rl" if pkg == "catmip_rl" else "env"
    if len(rest) > 1:  # a folder: catmip_env/kernels/, catmip_rl/store/, ...
        return f"{short}: {rest[0]}"
    if pkg == "catmip_rl":
        return "rl: package"
    if not any(t.count(".") >= 2 for t in _env_imports(module)):  # imports no catmip_env.<folder>.<module>
        return "env: base"
    users = [m for m in _modules() if m.startswith("catmip_env.") and module in _env_imports(m)]
    if all(m.endswith("__init__") for m in users):
        return "env: face"  # imported by no module of the package: the demo, the package's __init__
    return f"env: {rest[0]}"  # a flat module between the folders (play: the episode loop)


@cache
def _env_imports(module: str) -> list[str]:
    """The project modules a module of catmip_env imports (resolved as :func:`import_graph` does)."""
    mods = _modules()
    out = []
    for target, names, _ in imports(mods[module], module):
        out += [f"{target}.{n}" for n in names if f"{target}.{n}" in mods]
        if target in mods:
            out.append(target)
    return out


@cache
def _modules() -> dict[str, Path]:
    return modules()


def imports(path: Path, module: str) -> list[tuple[str, list[str], bool]]:
    """(imported module, names taken from it, lazy) for every import statement in the file; ``lazy``:
    inside a function (imported only when that runs)."""
    out = []
    tree = ast.parse(path.read_text(), str(path))
    nested = {id(n) for f in ast.walk(tree) if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef))
              for n in ast.walk(f)}  # fmt: skip
    for node in ast.walk(tree):
        lazy = id(node) in nested
        if isinstance(node, ast.Import):
            out += [(a.name, [], lazy) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: resolve against this module's package
                pkg = module.split(".")[: len(module.split(".")) - node.level + (path.name == "__init__.py")]
                base = ".".join(pkg + ([base] if base else []))
            out.append((base, [a.name for a in node.names], lazy))
    return out


def import_graph(root: Path = ROOT, lazy: bool = True) -> dict[str, set[str]]:
    """module -> the project modules it imports (``from pkg import submodule`` counts as the submodule);
    without ``lazy``, only the imports at module level."""
    mods = modules(root)
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for mod, path in mods.items():
        for target, names, is_lazy in imports(path, mod):
            if is_lazy and not lazy:
                continue
            for name in names:
                if f"{target}.{name}" in mods:
                    graph[mod].add(f"{target}.{name}")
            if target in mods and not all(f"{target}.{n}" in mods for n in names or ["?"]):
                graph[mod].add(target)
    for mod in graph:
        graph[mod].discard(mod)
    return graph


def group_edges(graph: dict[str, set[str]]) -> set[tuple[str, str]]:
    """(importing group, imported group) pairs; package __init__ re-exports are left out (they only
    gather names for users)."""
    edges = set()
    for mod, targets in graph.items():
        if mod.endswith("__init__"):
            continue
        for t in targets:
            if not t.endswith("__init__") and group(mod) != group(t):
                edges.add((group(mod), group(t)))
    return edges
