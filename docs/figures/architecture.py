"""Draw docs/figures/architecture.png from the code: every module of catmip_env and catmip_rl in its
group, and an arrow wherever a module of one group imports one of another (lazy imports included).

    python docs/figures/architecture.py [--out docs/figures/architecture.png]

``tests/test_architecture.py`` reads the same graph (:func:`import_graph`) and checks the rules the
picture shows: no import cycle, no private name imported across modules, the layers point one way.
"""

from __future__ import annotations

import argparse
import ast
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("catmip_env", "catmip_rl")

# catmip_env is one flat folder, layered: its groups, lowest first (catmip_rl's groups are its folders)
ENV_GROUPS = {
    "env: config": ("constants", "config", "rng", "ascii_maps", "files", "numba_cache", "__init__"),
    "env: state": ("state",),
    "env: numba kernels": ("mapgen", "sensing", "bfs", "dynamics", "macro", "observe"),
    "env: world": ("world",),
    "env: events": ("events", "decision_stats"),
    "env: planners": ("planners", "window_planner"),
    "env: play": ("play", "map_sets", "render", "demo"),
    "env: PettingZoo": ("search_rescue_v0", "spaces"),
}
RL_TOP = {"__init__": "rl: checkpoint", "checkpoint": "rl: checkpoint", "files": "rl: checkpoint"}
# where each group's box is drawn (x, y of its centre, in box units)
POSITION = {
    "env: config": (0, 0), "env: state": (0, 1), "env: numba kernels": (0, 2), "env: world": (0, 3),
    "env: events": (0, 4), "env: planners": (-1, 5), "env: play": (0.2, 6), "env: PettingZoo": (-1, 7),
    "rl: amat": (2.2, 3), "rl: training": (2.2, 5), "rl: checkpoint": (3.4, 6.5), "rl: evaluation": (2, 7),
    "rl: adapters": (4, 4), "rl: cli": (3.4, 8),
}  # fmt: skip


def modules(root: Path = ROOT) -> dict[str, Path]:
    """Dotted module name -> file, for every module of the two packages."""
    out = {}
    for pkg in PACKAGES:
        for path in sorted((root / pkg).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            out[".".join(parts)] = path
    return out


def group(module: str) -> str:
    """The box a module is drawn in (KeyError for a module no group names: add it to ENV_GROUPS)."""
    pkg, *rest = module.split(".")
    if pkg == "catmip_rl":
        return f"rl: {rest[0]}" if len(rest) > 1 else RL_TOP[rest[0]]
    name = rest[0] if rest else "__init__"
    return next(g for g, names in ENV_GROUPS.items() if name in names)


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


def reduce_edges(edges: set[tuple[str, str]]) -> set[tuple[str, str]]:
    """The edges not implied by a longer path (the transitive reduction of an acyclic graph): what the
    picture draws, so that each arrow says "depends on, directly or through the boxes it points to"."""
    nxt: dict[str, set[str]] = {}
    for a, b in edges:
        nxt.setdefault(a, set()).add(b)

    def reaches(a: str, b: str, skip: tuple[str, str]) -> bool:
        seen, todo = set(), [a]
        while todo:
            x = todo.pop()
            for y in nxt.get(x, ()):
                if (x, y) == skip or y in seen:
                    continue
                if y == b:
                    return True
                seen.add(y)
                todo.append(y)
        return False

    return {e for e in edges if not reaches(*e, skip=e)}


def _border(c0: tuple[float, float], c1: tuple[float, float], w: float, h: float) -> tuple[float, float]:
    """Where the segment from box centre ``c0`` towards ``c1`` leaves the w x h box around ``c0``."""
    dx, dy = c1[0] - c0[0], c1[1] - c0[1]
    s = min(w / 2 / abs(dx) if dx else float("inf"), h / 2 / abs(dy) if dy else float("inf"))
    return c0[0] + s * dx, c0[1] + s * dy


def draw(out: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import FancyBboxPatch

    graph = import_graph()
    members: dict[str, list[str]] = {}
    for mod in graph:
        if not mod.endswith("__init__"):
            members.setdefault(group(mod), []).append(mod.rsplit(".", 1)[1])
    w, h, sx, sy = 1.9, 0.66, 1.75, 1.0
    fig, ax = plt.subplots(figsize=(13, 10))
    centre = {g: (x * sx, y * sy) for g, (x, y) in POSITION.items()}
    eager = reduce_edges(group_edges(import_graph(lazy=False)))  # the layers: acyclic
    lazy = group_edges(graph) - group_edges(import_graph(lazy=False))  # optional paths (extras)
    for a, b in sorted(eager | lazy):
        (x0, y0), (x1, y1) = _border(centre[a], centre[b], w, h), _border(centre[b], centre[a], w, h)
        solid = (a, b) in eager
        style = dict(arrowstyle="-|>", color="0.45", lw=0.9, shrinkA=0, shrinkB=1)
        style |= dict(linestyle="-" if solid else "--", connectionstyle=f"arc3,rad={0 if solid else 0.25}")
        ax.annotate("", xy=(x1, y1), xytext=(x0, y0), zorder=1, arrowprops=style)
    for g, (x, y) in centre.items():
        env = g.startswith("env")
        fill, edge = ("#e8f1fb", "#2f6fb0") if env else ("#fdf0e3", "#c06a16")
        box = FancyBboxPatch((x - w / 2, y - h / 2), w, h, boxstyle="round,pad=0.03", fc=fill, ec=edge)
        box.set_zorder(2)
        ax.add_patch(box)
        names = sorted(members.get(g, []))
        lines = textwrap.wrap(", ".join(names), 40)
        ax.text(
            x, y + h / 2 - 0.08, g.split(": ")[1], ha="center", va="top", fontsize=10, weight="bold", zorder=3
        )
        ax.text(x, y + h / 2 - 0.27, "\n".join(lines), ha="center", va="top", fontsize=7, zorder=3)
    ax.text(0, -0.75, "catmip_env (numpy + numba, no torch)", ha="center", color="#2f6fb0", fontsize=11)
    ax.text(5.2, 2.2, "catmip_rl (torch)", ha="center", color="#c06a16", fontsize=11)
    ax.text(7.0, 3.5, "the only TorchRL / Ray imports", ha="center", va="center", fontsize=8, color="0.35")
    ax.set_xlim(-2.8, 8.4)
    ax.set_ylim(-1.1, 8.6)
    ax.set_axis_off()
    ax.set_title(
        "CATMiP modules by group. Arrow: imports at module level, directly or through the box it points to;\n"
        "dashed: imported only inside a function (e.g. the Ray extra). Drawn by docs/figures/architecture.py",
        fontsize=11,
    )
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(ROOT / "docs" / "figures" / "architecture.png"))
    print("wrote", draw(Path(ap.parse_args().out)))


if __name__ == "__main__":
    main()
