"""Draw docs/figures/architecture.png from the code: every module of catmip_env and catmip_rl in its
group, and an arrow wherever a module of one group imports one of another (lazy imports included).

    python docs/figures/architecture.py [--out docs/figures/architecture.png]

The groups and the import graph are those ``tests/test_architecture.py`` checks (no import cycle, no
private name imported across modules, each name from the module that defines it, the layers point one
way), from ``tests/architecture_graph.py``.
"""

from __future__ import annotations

import argparse
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
from tests.architecture_graph import group, group_edges, import_graph  # noqa: E402

# where each group's box is drawn (x, y of its centre, in box units)
POSITION = {
    "env: base": (0, 0),
    "env: kernels": (0, 1.3),
    "env: engines": (0, 2.6),
    "env: maps": (-0.95, 3.9),
    "env: planners": (0.45, 3.9),
    "env: play": (0.45, 6.5),
    "env: face": (0, 9.1),
    "env: runtime": (-0.95, 5.2),
    "env: envs": (-0.95, 7.8),
    "rl: amat": (2.2, 3),
    "rl: package": (4.2, 3),
    "rl: store": (3.4, 4.2),
    "rl: training": (2.2, 5.2),
    "rl: adapters": (4.2, 6),
    "rl: evaluation": (2, 7),
    "rl: benchmark": (3.4, 8.2),
    "rl: cli": (1.6, 9.2),
}


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
    fig, ax = plt.subplots(figsize=(13, 11))
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
    ax.text(7.35, 6.45, "the only TorchRL / Ray imports", ha="center", va="center", fontsize=8, color="0.35")
    ax.set_xlim(-2.8, 8.4)
    ax.set_ylim(-1.1, 9.8)
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
