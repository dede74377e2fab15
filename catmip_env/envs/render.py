"""Rendering in the paper's Fig. 4 style, and episode-to-GIF export.

:func:`render_world` draws one world of an engine as an (H*cell, W*cell, 3) uint8 picture with numpy
only: free cells white, walls dark grey, obstacles black, target green, clues pink, cells no robot has
explored dimmed, robots as class-coloured triangles pointing along their heading, each robot's goal as
a ring of its colour, and (optionally) communication links between neighbourhood members.
:func:`save_gif` writes a list of frames (needs the ``render`` extra: ``imageio``);
:func:`episode_frames` / :func:`render_episode` draw a policy playing one episode (one frame per tick),
each frame captioned (:func:`add_caption`, the ``render`` extra's pillow) with the tick, the episode's
state (:func:`episode_status`: searching, target found, rescued or not by the horizon) and a legend.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path

import numpy as np

from catmip_env.constants import CLUE, EXPLORED, OBSTACLE, TARGET, WALL
from catmip_env.engines.events import EventEngine
from catmip_env.play import Policy, play
from catmip_env.runtime.files import atomic_path

__all__ = [
    "render_world",
    "render_ansi",
    "episode_status",
    "add_caption",
    "save_gif",
    "episode_frames",
    "render_episode",
    "LiveWindow",
    "CLASS_COLOURS",
    "RENDER_FPS",
]

RENDER_FPS = 8
"""Frames (ticks) per second of a rendered episode: the env's ``metadata["render_fps"]`` and the GIFs'."""

_FREE = np.array([255, 255, 255], np.uint8)
_COLOURS = {
    WALL: np.array([70, 70, 70], np.uint8),
    OBSTACLE: np.array([20, 20, 20], np.uint8),
    TARGET: np.array([40, 170, 60], np.uint8),
    CLUE: np.array([245, 160, 200], np.uint8),
}
#: Robot colours by class index (rescuers red, explorers blue in the default class order).
CLASS_COLOURS = np.array(
    [[220, 40, 40], [40, 90, 220], [230, 150, 20], [140, 60, 180], [20, 160, 160], [120, 120, 0]],
    np.uint8,
)
_UNEXPLORED_DIM = 0.55  # brightness of cells nobody has explored


@lru_cache(maxsize=8)
def _triangle_masks(cell: int) -> np.ndarray:
    """(4, cell, cell) bool triangles pointing E, S, W, N."""
    y, x = np.mgrid[0:cell, 0:cell] + 0.5
    u, v = x / cell, y / cell  # u: rightward, v: downward, in [0, 1]
    east = (u >= 0.15) & (u <= 0.88) & (np.abs(v - 0.5) <= 0.42 * (0.88 - u) / 0.73)
    return np.stack([east, np.rot90(east, -1), np.rot90(east, 2), np.rot90(east, 1)])


@lru_cache(maxsize=8)
def _ring_mask(cell: int) -> np.ndarray:
    y, x = np.mgrid[0:cell, 0:cell] + 0.5
    d = np.hypot(x - cell / 2, y - cell / 2) / cell
    return (d <= 0.45) & (d >= 0.30)


def _line(img: np.ndarray, p0: tuple[float, float], p1: tuple[float, float], colour) -> None:
    n = int(max(abs(p1[0] - p0[0]), abs(p1[1] - p0[1]))) + 1
    rr = np.linspace(p0[0], p1[0], n).round().astype(int)
    cc = np.linspace(p0[1], p1[1], n).round().astype(int)
    ok = (rr >= 0) & (rr < img.shape[0]) & (cc >= 0) & (cc < img.shape[1])
    img[rr[ok], cc[ok]] = colour


def render_world(engine, b: int = 0, cell: int = 16, links: bool = True) -> np.ndarray:
    """Picture of world ``b`` of a :class:`~catmip_env.engines.world.BatchedWorld` (uint8, H x W x 3)."""
    st = engine.state
    grid = st.grid[b]
    h, w = grid.shape
    base = np.empty((h, w, 3), np.uint8)
    base[:] = _FREE
    for code, colour in _COLOURS.items():
        base[grid == code] = colour
    explored = (st.belief[b] & EXPLORED).any(axis=0)
    base[~explored] = (base[~explored] * _UNEXPLORED_DIM).astype(np.uint8)
    img = np.repeat(np.repeat(base, cell, axis=0), cell, axis=1)
    # faint grid lines
    img[::cell, :] = (img[::cell, :] * 0.85).astype(np.uint8)
    img[:, ::cell] = (img[:, ::cell] * 0.85).astype(np.uint8)
    n = st.pos.shape[1]
    colours = CLASS_COLOURS[st.cls[b] % len(CLASS_COLOURS)]
    if links:
        for i in range(n):
            for j in range(i + 1, n):
                if st.comp[b, i] == st.comp[b, j]:
                    p0 = (st.pos[b, i] + 0.5) * cell
                    p1 = (st.pos[b, j] + 0.5) * cell
                    _line(img, tuple(p0), tuple(p1), np.array([150, 150, 150], np.uint8))
    ring = _ring_mask(cell)
    for i in range(n):
        gr, gc = st.goal[b, i]
        if gr >= 0:
            tile = img[gr * cell : (gr + 1) * cell, gc * cell : (gc + 1) * cell]
            tile[ring] = colours[i]
    tri = _triangle_masks(cell)
    for i in range(n):
        r, c = st.pos[b, i]
        tile = img[r * cell : (r + 1) * cell, c * cell : (c + 1) * cell]
        tile[tri[st.heading[b, i]]] = colours[i]
    return img


def render_ansi(engine, b: int = 0) -> str:
    """Text picture: ``#`` wall, ``o`` obstacle, ``T`` target, ``+`` clue, ``?`` unexplored,
    robots as ``>v<^`` (their heading)."""
    st = engine.state
    grid = st.grid[b]
    explored = (st.belief[b] & EXPLORED).any(axis=0)
    chars = {0: ".", WALL: "#", OBSTACLE: "o", TARGET: "T", CLUE: "+"}
    rows = [
        [chars[int(v)] if explored[r, c] else "?" for c, v in enumerate(row)] for r, row in enumerate(grid)
    ]
    for i in range(st.pos.shape[1]):
        r, c = st.pos[b, i]
        rows[r][c] = ">v<^"[st.heading[b, i]]
    return "\n".join("".join(row) for row in rows)


def episode_status(engine, b: int = 0) -> str:
    """One line on world ``b``'s episode: the tick and how the mission stands, e.g. "tick 37 / 300 ·
    target found at tick 21" or, once it is over, "tick 52 / 300 · RESCUED at tick 52"."""
    st, horizon = engine.state, engine.cfg.horizon_ticks
    if st.rescue_tick[b] >= 0:
        state = f"RESCUED at tick {st.rescue_tick[b]}"
    elif st.done[b]:
        state = f"NOT RESCUED by the horizon ({horizon} ticks)"
    elif st.informed_tick[b] >= 0:
        state = f"a rescuer knows the target (tick {st.informed_tick[b]})"
    elif st.found_tick[b] >= 0:
        state = f"target found at tick {st.found_tick[b]}"
    else:
        state = "searching"
    return f"tick {st.ticks[b]} / {horizon} · {state}"


def _legend(engine, b: int) -> list[tuple[str, str, tuple[int, int, int]]]:
    """(shape, label, colour) of each legend entry: the classes in world ``b``, then the cell kinds."""
    classes = sorted(set(engine.state.cls[b].tolist()))
    robots = [("robot", engine.cfg.classes[c].name, CLASS_COLOURS[c % len(CLASS_COLOURS)]) for c in classes]
    cells = [
        ("ring", "goal", (90, 90, 90)),
        ("cell", "target", _COLOURS[TARGET]),
        ("cell", "clue", _COLOURS[CLUE]),
        ("cell", "unexplored", (140, 140, 140)),
        ("line", "radio link", (150, 150, 150)),
    ]
    return [(shape, label, tuple(int(v) for v in colour)) for shape, label, colour in robots + cells]


def add_caption(img: np.ndarray, engine, b: int = 0) -> np.ndarray:
    """``img`` (a :func:`render_world` picture of world ``b``) with a strip below it: the
    :func:`episode_status` line and a legend. The strip's height depends only on the width and the
    classes in the world, so every frame of an episode has one shape. Needs pillow (``render`` extra)."""
    try:
        from PIL import Image, ImageDraw, ImageFont
    except ImportError as err:  # pragma: no cover - depends on the extra
        raise ImportError("captions need pillow: pip install 'catmip[render]' (or caption=False)") from err
    font = ImageFont.load_default()
    width, line, sw = img.shape[1], 14, 9  # pixels: the width, a text line, a legend swatch
    rows: list[list[tuple[int, tuple]]] = [[]]  # legend entries flowed into rows: (x, entry)
    x = 4
    for entry in _legend(engine, b):
        w = sw + 4 + int(font.getlength(entry[1])) + 10
        if x + w > width and rows[-1]:
            rows.append([])
            x = 4
        rows[-1].append((x, entry))
        x += w
    strip = Image.new("RGB", (width, 6 + line * (1 + len(rows))), (255, 255, 255))
    draw = ImageDraw.Draw(strip)
    draw.text((4, 3), episode_status(engine, b), fill=(0, 0, 0), font=font)
    for k, row in enumerate(rows):
        y = 3 + line * (k + 1)
        for x, (shape, label, colour) in row:
            box = (x, y + 1, x + sw, y + 1 + sw)
            if shape == "robot":
                draw.polygon([(x, y + 1), (x + sw, y + 1 + sw // 2), (x, y + 1 + sw)], fill=colour)
            elif shape == "ring":
                draw.ellipse(box, outline=colour, width=2)
            elif shape == "line":
                draw.line((x, y + 1 + sw // 2, x + sw, y + 1 + sw // 2), fill=colour, width=2)
            else:
                draw.rectangle(box, fill=colour, outline=(60, 60, 60))
            draw.text((x + sw + 4, y), label, fill=(0, 0, 0), font=font)
    return np.concatenate([img, np.asarray(strip, np.uint8)], axis=0)


def save_gif(frames: Sequence[np.ndarray], path: str | Path, fps: int = 8) -> Path:
    """Write frames to an animated GIF at ``path`` (must end in ``.gif``; ``fps`` >= 1), atomically: a
    temporary file is renamed into place, and removed if writing fails."""
    try:
        import imageio.v3 as iio
    except ImportError as err:  # pragma: no cover - depends on the extra
        raise ImportError("save_gif needs imageio: pip install 'catmip[render]'") from err
    if not frames:
        raise ValueError("save_gif needs at least one frame")
    path = Path(path)
    if path.suffix.lower() != ".gif":
        raise ValueError(f"{path}: save_gif writes an animated GIF, so the path must end in .gif")
    if path.is_dir():
        raise IsADirectoryError(f"{path} is a folder: save_gif needs a file path ending in .gif")
    if not isinstance(fps, int) or fps < 1:
        raise ValueError(f"fps must be an int >= 1, got {fps!r}")
    with atomic_path(path) as tmp:
        iio.imwrite(tmp, np.stack(frames), duration=1000 / fps, loop=0)
    return path


def episode_frames(
    engine: EventEngine, policy: Policy, episode: int = 0, max_frames: int = 400, caption: bool = True
) -> list[np.ndarray]:
    """Frames of ``policy`` playing episode index ``episode`` in world 0 of ``engine`` (a one-world
    engine; it is reset): the start, then one frame per tick (the engine pauses after every tick), until
    the episode ends or there are ``max_frames``; ``caption``: each with :func:`add_caption`'s strip."""

    def frame(eng: EventEngine) -> np.ndarray:
        img = render_world(eng.world, 0)
        return add_caption(img, eng.world, 0) if caption else img

    engine.reset(episode_indices=[episode])
    frames = [frame(engine)]
    play(
        engine,
        policy,
        on_event=lambda eng: frames.append(frame(eng)),
        until=lambda _: len(frames) >= max_frames,
        max_ticks=1,
    )
    return frames


def render_episode(
    engine: EventEngine,
    policy: Policy,
    path: str | Path,
    episode: int = 0,
    fps: int = 8,
    max_frames: int = 400,
    caption: bool = True,
) -> Path:
    """GIF at ``path`` of :func:`episode_frames` (``fps`` frames, i.e. ticks, per second)."""
    return save_gif(episode_frames(engine, policy, episode, max_frames, caption), path, fps=fps)


class LiveWindow:
    """A live matplotlib window showing one frame after another (the PettingZoo env's human mode)."""

    def __init__(self) -> None:
        import matplotlib.pyplot as plt

        self._fig, ax = plt.subplots()
        ax.set_axis_off()
        self._im = None
        self._ax = ax

    def show(self, frame: np.ndarray) -> None:
        import matplotlib.pyplot as plt

        if self._im is None:
            self._im = self._ax.imshow(frame)
        else:
            self._im.set_data(frame)
        self._fig.canvas.draw_idle()
        plt.pause(1e-3)

    def close(self) -> None:
        import matplotlib.pyplot as plt

        plt.close(self._fig)
