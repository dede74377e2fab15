"""Hand-drawn ASCII maps, for tests, demos and custom tasks.

Legend (one character per cell, rows top to bottom; rows may differ from columns)::

    #  wall            o  obstacle         T  target (exactly one)
    .  free cell       0-9 / A-F  robot_0 ... robot_15 standing on a free cell

Clue cells are not drawn: every free cell among the target's 8 neighbours becomes a clue, as in
generated maps. Robots start facing east unless a last line ``headings: E S W N`` (one letter per
robot, in id order) says otherwise. Leading/trailing blank lines and common indentation are ignored.
A robot may not start next to the target (the mission would be over before it began), and every robot
must be able to reach a cell next to it (as on generated maps; walls and obstacles block, robots do not).
"""

from __future__ import annotations

import textwrap
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from catmip_env.constants import CLUE, FREE, OBSTACLE, STEPS, TARGET, WALL

__all__ = ["Layout", "parse_layout"]

_ROBOT_CHARS = "0123456789ABCDEF"
_TERRAIN = {"#": WALL, "o": OBSTACLE, ".": FREE}  # cell codes of the characters that are only terrain


@dataclass(frozen=True)
class Layout:
    grid: np.ndarray  # (H, W) uint8 cell codes (types.FREE ... types.CLUE)
    robots: np.ndarray  # (N, 2) int64 robot cells, in id order
    target: tuple[int, int]
    headings: tuple[int, ...]  # per robot, 0=E 1=S 2=W 3=N

    @property
    def num_robots(self) -> int:
        return len(self.robots)


@lru_cache(maxsize=64)
def parse_layout(text: str) -> Layout:
    """Parse an ASCII map; raises ``ValueError`` naming the problem for malformed maps."""
    lines, heading_letters = _map_rows(text)
    grid, robots, target = _read_cells(lines)
    _check_pieces(grid, robots)
    headings = _read_headings(heading_letters, len(robots))
    tr, tc = target
    for i, (r, c) in robots.items():
        if abs(r - tr) <= 1 and abs(c - tc) <= 1:
            raise ValueError(f"layout robot {i} starts next to the target")
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if (dr or dc) and grid[tr + dr, tc + dc] == FREE:
                grid[tr + dr, tc + dc] = CLUE
    _check_target_reachable(grid, robots, target)
    robot_cells = np.array([robots[i] for i in range(len(robots))], dtype=np.int64)
    grid.setflags(write=False)
    robot_cells.setflags(write=False)
    return Layout(grid=grid, robots=robot_cells, target=target, headings=headings)


def _map_rows(text: str) -> tuple[list[str], list[str] | None]:
    """The map's rows (dedented and stripped, blank lines dropped; equally long, at least 3x3) and the
    letters of its ``headings:`` line (None without one)."""
    lines = [ln.rstrip() for ln in textwrap.dedent(text).strip("\n").splitlines()]
    lines = [ln for ln in lines if ln.strip()]
    heading_letters = None
    if lines and lines[-1].strip().lower().startswith("headings:"):
        heading_letters = lines.pop().split(":", 1)[1].split()
    lines = [ln.strip() for ln in lines]
    if not lines:
        raise ValueError("layout is empty")
    width = len(lines[0])
    if any(len(ln) != width for ln in lines):
        raise ValueError(f"layout rows have different lengths: {[len(ln) for ln in lines]}")
    h, w = len(lines), width
    if h < 3 or w < 3:
        raise ValueError(f"layout must be at least 3x3, got {h}x{w}")
    return lines, heading_letters


def _read_cells(lines: list[str]) -> tuple[np.ndarray, dict[int, tuple[int, int]], tuple[int, int]]:
    """The grid of cell codes (no clues yet), each robot's cell by id and the target's cell, read
    character by character; a second target or robot, or an unknown character, is refused where met."""
    grid = np.full((len(lines), len(lines[0])), FREE, dtype=np.uint8)
    robots: dict[int, tuple[int, int]] = {}
    target = None
    for r, line in enumerate(lines):
        for c, ch in enumerate(line):
            if ch in _TERRAIN:
                grid[r, c] = _TERRAIN[ch]
            elif ch == "T":
                if target is not None:
                    raise ValueError(f"layout has more than one target (second at {(r, c)})")
                target = (r, c)
                grid[r, c] = TARGET
            elif ch in _ROBOT_CHARS:
                i = _ROBOT_CHARS.index(ch)
                if i in robots:
                    raise ValueError(f"layout places robot {ch} twice")
                robots[i] = (r, c)
            else:
                raise ValueError(f"unknown layout character {ch!r} at row {r}, col {c}")
    if target is None:
        raise ValueError("layout has no target 'T'")
    return grid, robots, target


def _check_pieces(grid: np.ndarray, robots: dict[int, tuple[int, int]]) -> None:
    """ValueError unless there are robots, numbered 0 .. N-1, and the map is enclosed by walls."""
    if not robots:
        raise ValueError("layout has no robot (digits 0-9 or A-F)")
    if sorted(robots) != list(range(len(robots))):
        raise ValueError(f"layout robot ids must be 0..N-1 without gaps, got {sorted(robots)}")
    border = np.concatenate([grid[0], grid[-1], grid[:, 0], grid[:, -1]])
    if not np.all(border == WALL):
        raise ValueError("layout must be enclosed by a ring of walls '#'")


def _read_headings(letters: list[str] | None, n: int) -> tuple[int, ...]:
    """Each of the ``n`` robots' heading (0=E 1=S 2=W 3=N) from the ``headings:`` letters; east without."""
    if letters is None:
        return (0,) * n
    if len(letters) != n or any(x.upper() not in "ESWN" for x in letters):
        raise ValueError(f"layout 'headings:' line must give one of E/S/W/N per robot ({n}), got {letters}")
    return tuple("ESWN".index(x.upper()) for x in letters)


def _check_target_reachable(
    grid: np.ndarray, robots: dict[int, tuple[int, int]], target: tuple[int, int]
) -> None:
    """ValueError unless every robot can walk (4-connected, over free and clue cells; robots make way) to
    a cell next to the target: the target itself is impassable, and a rescue is made from beside it.
    One flood fill from the target's sides (plain Python: mapgen's numba fill is a layer above this)."""
    passable = ((grid == FREE) | (grid == CLUE)).tolist()
    seen = [[False] * len(row) for row in passable]
    tr, tc = target
    todo = [(tr + dr, tc + dc) for dr, dc in STEPS]  # the walled border keeps every step inside the grid
    while todo:
        r, c = todo.pop()
        if passable[r][c] and not seen[r][c]:
            seen[r][c] = True
            todo += [(r + dr, c + dc) for dr, dc in STEPS]
    cut_off = [i for i, (r, c) in sorted(robots.items()) if not seen[r][c]]
    if cut_off:
        raise ValueError(
            f"layout target {target} is unreachable from the start of robot(s) {cut_off}: walls and "
            "obstacles cut them off from every cell next to the target"
        )
