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

from catmip_env import make_config
from catmip_env.engines.episode_stats import episode_metrics
from catmip_env.engines.events import EventEngine
from catmip_env.envs.render import render_episode
from catmip_env.planners.baselines import PLANNERS, make_planner
from catmip_env.play import play
from catmip_env.runtime.files import atomic_path
from catmip_env.runtime.warmup import compile_kernels

DEFAULT_PLANNERS = ("nearest", "utility", "rrt", "apf", "random-frontier", "random-rescue", "random-uniform")


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

    def progress(engine: EventEngine) -> None:
        if bar is not None and int(engine.state.done.sum()) > bar.n:
            bar.update(int(engine.state.done.sum()) - bar.n)

    t0 = time.perf_counter()
    metrics = episode_metrics(play(eng, policy, on_event=progress), cfg.horizon_ticks)
    if bar is not None:
        bar.close()
    keys = (
        "success_rate",
        "success_by_100",
        "mean_rescue_tick",
        "mean_target_found_tick",
        "mean_explored_fraction",
        "decisions",
    )
    row = {"planner": planner, "preset": preset, "episodes": episodes, "seed": seed}
    return row | {k: metrics[k] for k in keys} | {"seconds": time.perf_counter() - t0}


def _write(out: Path, rows: list[dict]) -> None:
    with atomic_path(out / "results.json") as tmp:
        tmp.write_text(json.dumps(rows, indent=2))
    with atomic_path(out / "results.csv") as tmp, tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


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
    compile_kernels()  # the first run on a machine: say so and how long it takes
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
    # episode 0 of the seed, one frame per tick between events
    eng = EventEngine(make_config(args.preset), 1, seed=args.seed, goal_mode="cell")
    gif = render_episode(eng, make_planner(best["planner"], seed=args.seed), out / "episode.gif", fps=6)
    print(f"wrote {out / 'results.json'}, {out / 'results.csv'} and {gif} ({best['planner']})")
    return rows


if __name__ == "__main__":
    main()
