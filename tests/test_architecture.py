"""The rules docs/architecture.md states, checked on the import graph of tests/architecture_graph.py
(which docs/figures/architecture.py draws)."""

from __future__ import annotations

import ast
import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_LINES = 400


@pytest.fixture(scope="module")
def arch():
    """The checked structure: modules, groups, import graph."""
    from tests import architecture_graph

    return architecture_graph


@pytest.fixture(scope="module")
def picture():
    """docs/figures/architecture.py, which draws it."""
    path = ROOT / "docs" / "figures" / "architecture.py"
    spec = importlib.util.spec_from_file_location("architecture", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["architecture"] = mod
    try:
        spec.loader.exec_module(mod)
        yield mod
    finally:
        sys.modules.pop("architecture", None)


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as a list of nodes, or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        state[n] = 1
        stack.append(n)
        for m in sorted(graph.get(n, ())):
            if state.get(m) == 1:
                return stack[stack.index(m) :] + [m]
            if m not in state and (found := visit(m)):
                return found
        state[n] = 2
        stack.pop()
        return None

    for n in sorted(graph):
        if n not in state and (found := visit(n)):
            return found
    return None


def test_cycle_finder_finds_cycles():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None


def test_no_import_cycle_between_modules(arch):
    assert _cycle(arch.import_graph()) is None


def test_the_groups_are_layered(arch):
    """Module-level imports between the diagram's groups never loop back (lazy imports of optional
    extras, drawn dashed, may point up: the TorchRL/Ray adapters are imported by training only for
    ``collector="ray"``)."""
    edges = arch.group_edges(arch.import_graph(lazy=False))
    graph: dict[str, set[str]] = {}
    for a, b in edges:
        graph.setdefault(a, set()).add(b)
    assert _cycle(graph) is None


def test_every_module_is_in_the_picture(arch, picture):
    for mod in arch.import_graph():
        assert arch.group(mod) in picture.POSITION, mod


def test_no_private_name_imported_across_modules(arch):
    bad = []
    for mod, path in arch.modules().items():
        for target, names, _ in arch.imports(path, mod):
            if target.split(".")[0] in arch.PACKAGES:
                bad += [
                    f"{mod} imports {target}.{n}" for n in names if n.startswith("_") and n != "__version__"
                ]
    assert not bad


def _defined(path: Path) -> set[str]:
    """Names a module defines at its top level (functions, classes, assignments), not ones it imports."""
    out = set()
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            out.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            out |= {n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)}
    return out


def test_each_name_is_imported_from_the_module_that_defines_it(arch):
    """One import path per name: inside the packages, ``from M import X`` takes X from the module that
    defines it (or X is a submodule of package M), never from a module that only re-exports it."""
    mods = arch.modules()
    bad = []
    for mod, path in mods.items():
        for target, names, _ in arch.imports(path, mod):
            if target in mods and target != mod:
                ok = _defined(mods[target]) | {"__version__"}
                bad += [f"{mod}: from {target} import {n}" for n in names
                        if n not in ok and f"{target}.{n}" not in mods]  # fmt: skip
    assert not bad


def test_modules_stay_small(arch):
    """No module over MAX_LINES lines: a newcomer reads one file for one job."""
    sizes = {m: len(p.read_text().splitlines()) for m, p in arch.modules().items()}
    assert {m: n for m, n in sizes.items() if n > MAX_LINES} == {}


def test_no_function_over_100_lines(arch):
    long = []
    for mod, path in arch.modules().items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > 100:
                    long.append(f"{mod}.{node.name}: {n} lines")
    assert not long


def test_env_never_imports_torch_or_catmip_rl(arch):
    for mod, path in arch.modules().items():
        if mod.startswith("catmip_env"):
            roots = {t.split(".")[0] for t, _, _ in arch.imports(path, mod)}
            assert not roots & {"torch", "catmip_rl", "torchrl", "tensordict"}, mod


def test_torchrl_and_ray_only_in_adapters(arch):
    for mod, path in arch.modules().items():
        roots = {t.split(".")[0] for t, _, _ in arch.imports(path, mod)}
        if roots & {"torchrl", "tensordict", "ray"}:
            assert mod.startswith("catmip_rl.adapters."), mod


def test_the_model_does_not_depend_on_training_or_evaluation(arch):
    graph = arch.import_graph()
    for mod, targets in graph.items():
        if mod.startswith("catmip_rl.amat"):
            above = [t for t in targets if t.startswith(("catmip_rl.training", "catmip_rl.evaluation",
                                                         "catmip_rl.adapters", "catmip_rl.cli"))]  # fmt: skip
            assert not above, mod


def test_the_diagram_is_drawn(picture, tmp_path):
    png = picture.draw(tmp_path / "architecture.png")
    assert png.stat().st_size > 10_000
