"""Demo: the planning baselines on a batch of episodes, a results table, and a rendered GIF.

    python -m catmip_env.demo [--preset task1] [--episodes 32] [--seed 0] [--out out/demo]

Every planner plays the same ``--episodes`` maps (same seed → same maps) with the macro-action layer
(evaluation activation, goals in cell mode). The demo prints success rate, success by tick 100, mean
rescue and target-found ticks and explored fraction per planner, writes ``results.json`` and
``results.csv``, and renders the first episode of the best planner to ``episode.gif`` (one frame per
tick: robots, their goals as rings, explored area, communication links).
"""

from __future__ import annotations

import argparse
import csv
import json
import time
from pathlib import Path

import numpy as np

from catmip_env import make_config
from catmip_env.events import EventEngine
from catmip_env.planners import PLANNERS, make_planner
from catmip_env.render import render_world, save_gif

DEFAULT_PLANNERS = ("nearest", "utility", "rrt", "apf", "random-frontier", "random")


def _progress(total: int, desc: str):
    try:
        from tqdm import tqdm

        return tqdm(total=total, desc=desc, unit="ep", leave=False, mininterval=0.5)
    except ImportError:  # tqdm comes with the render/dev extras
        return None


def evaluate(planner: str, preset: str, episodes: int, seed: int) -> dict:
    """Run ``episodes`` worlds (episode indices 0..episodes-1 of ``seed``) to their end."""
    cfg = make_config(preset)
    eng = EventEngine(cfg, num_worlds=episodes, seed=seed, goal_mode="cell")
    policy = make_planner(planner, seed=seed)
    eng.reset()
    bar = _progress(episodes, f"{planner:>16}")
    explored = np.zeros(episodes)
    t0, decisions = time.perf_counter(), 0
    while not eng.state.done.all():
        live = ~eng.state.done
        decisions += int((eng.active & live[:, None]).sum())
        eng.step(policy.act(eng))
        explored = np.where(live, eng.world.explored_fraction(), explored)
        if bar is not None and int(eng.state.done.sum()) > bar.n:
            bar.update(int(eng.state.done.sum()) - bar.n)
    if bar is not None:
        bar.close()
    st = eng.state
    rescued = st.rescue_tick >= 0
    found = st.found_tick >= 0
    return {
        "planner": planner,
        "preset": preset,
        "episodes": episodes,
        "seed": seed,
        "success_rate": float(rescued.mean()),
        "success_by_100": float((rescued & (st.rescue_tick <= 100)).mean()),
        "mean_rescue_tick": float(st.rescue_tick[rescued].mean()) if rescued.any() else None,
        "mean_target_found_tick": float(st.found_tick[found].mean()) if found.any() else None,
        "mean_explored_fraction": float(explored.mean()),
        "decisions": decisions,
        "seconds": time.perf_counter() - t0,
    }


def render_episode(planner: str, preset: str, seed: int, path: Path, max_frames: int = 400) -> Path:
    """GIF of episode 0 of ``seed`` played by ``planner``, one frame per tick between events."""
    eng = EventEngine(make_config(preset), 1, seed=seed, goal_mode="cell")
    policy = make_planner(planner, seed=seed)
    eng.reset(episode_indices=[0])
    frames = [render_world(eng.world, 0)]
    while not eng.state.done[0] and len(frames) < max_frames:
        eng.step(policy.act(eng), max_ticks=1)  # pause after every tick to draw it
        frames.append(render_world(eng.world, 0))
    return save_gif(frames, path, fps=6)


def _write(out: Path, rows: list[dict]) -> None:
    tmp = out / "results.json.tmp"
    tmp.write_text(json.dumps(rows, indent=2))
    tmp.replace(out / "results.json")
    tmp = out / "results.csv.tmp"
    with tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    tmp.replace(out / "results.csv")


def main(argv: list[str] | None = None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", default="task1", help="task1 | task2 | task3 | train")
    ap.add_argument("--episodes", type=int, default=32)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--planners", default=",".join(DEFAULT_PLANNERS), help=f"comma list of {sorted(PLANNERS)}"
    )
    ap.add_argument("--out", default="out/demo")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = [evaluate(p.strip(), args.preset, args.episodes, args.seed) for p in args.planners.split(",")]
    _write(out, rows)
    print(f"\n{args.episodes} episodes of {args.preset} (seed {args.seed}), same maps for every planner:")
    print(f"{'planner':>16} {'success':>8} {'by t=100':>9} {'rescue t':>9} {'found t':>8} {'explored':>9}")
    for r in rows:
        rescue = "-" if r["mean_rescue_tick"] is None else f"{r['mean_rescue_tick']:.1f}"
        found = "-" if r["mean_target_found_tick"] is None else f"{r['mean_target_found_tick']:.1f}"
        print(
            f"{r['planner']:>16} {r['success_rate']:>8.2f} {r['success_by_100']:>9.2f} {rescue:>9} "
            f"{found:>8} {r['mean_explored_fraction']:>9.2f}"
        )
    best = max(rows, key=lambda r: (r["success_by_100"], -(r["mean_rescue_tick"] or 1e9)))
    gif = render_episode(best["planner"], args.preset, args.seed, out / "episode.gif")
    print(f"wrote {out / 'results.json'}, {out / 'results.csv'} and {gif} ({best['planner']})")
    return rows


if __name__ == "__main__":
    main()
