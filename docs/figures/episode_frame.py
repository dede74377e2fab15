"""The README's picture: one frame of a Task-2 episode (σ = 2) played by ``rrt-relay-coord``, at the
tick the target is first seen, drawn by the env's own renderer (``catmip_env.envs.render``) with its caption.

    python docs/figures/episode_frame.py [--out docs/figures/episode.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from catmip_env import make_config
from catmip_env.engines.events import EventEngine
from catmip_env.envs.render import add_caption, render_world
from catmip_env.planners import make_planner


def frame(episode: int = 2, seed: int = 1000) -> np.ndarray:
    """The frame of the event at which a robot first sees the target (or the last one)."""
    engine = EventEngine(make_config("task2", comm_sigma=2.0), num_worlds=1, seed=seed, goal_mode="cell")
    engine.reset(episode_indices=[episode])
    planner = make_planner("rrt-relay-coord", seed=seed)
    while not engine.state.done[0] and engine.state.found_tick[0] < 0:
        engine.step(planner.act(engine))
    return add_caption(render_world(engine, 0, cell=16), engine, 0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path(__file__).with_name("episode.png"))
    args = ap.parse_args()
    import matplotlib.pyplot as plt

    plt.imsave(args.out, frame())
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
