"""Demo: a batch of primitive-level episodes with a forward-biased random walk, statistics and a GIF.

    python -m catmip_env.demo [--preset task1] [--episodes 64] [--seed 0] [--out out/demo]

Runs ``--episodes`` worlds of the batched engine to the end of their episodes, prints success rate,
rescue / target-found ticks, explored fraction and throughput, writes ``stats.json``, and renders the
first episode to ``episode.gif`` through the PettingZoo env (same seed and episode index, so it is the
same map). The walk moves forward with probability 0.7 and turns otherwise: a floor, not a planner.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from catmip_env import BatchedEngine, make_config, search_rescue_v0
from catmip_env.render import save_gif
from catmip_env.types import FORWARD, TURN_LEFT, TURN_RIGHT

WALK_PROBS = {FORWARD: 0.7, TURN_LEFT: 0.15, TURN_RIGHT: 0.15}


def random_walk(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    return rng.choice(list(WALK_PROBS), size=shape, p=list(WALK_PROBS.values()))


def _progress(total: int, desc: str):
    try:
        from tqdm import tqdm

        return tqdm(total=total, desc=desc, unit="tick")
    except ImportError:  # tqdm comes with the render/dev extras
        return None


def run_batch(preset: str, episodes: int, seed: int) -> dict:
    cfg = make_config(preset)
    eng = BatchedEngine(cfg, num_worlds=episodes, seed=seed)
    eng.reset()
    rng = np.random.default_rng(seed)
    bar = _progress(cfg.horizon_ticks, f"{episodes} x {preset}")
    ticks, t0 = 0, time.perf_counter()
    explored = np.zeros(episodes)
    while not eng.state.done.all():
        live = ~eng.state.done
        ticks += int(live.sum())
        eng.step(random_walk(rng, (episodes, eng.num_robots)))
        explored = np.where(live, eng.explored_fraction(), explored)
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    dt = time.perf_counter() - t0
    st = eng.state
    rescued = st.rescue_tick >= 0
    found = st.found_tick >= 0
    return {
        "preset": preset,
        "episodes": episodes,
        "seed": seed,
        "policy": "forward-biased random walk (primitive level)",
        "success_rate": float(rescued.mean()),
        "mean_rescue_tick": float(st.rescue_tick[rescued].mean()) if rescued.any() else None,
        "target_found_rate": float(found.mean()),
        "mean_target_found_tick": float(st.found_tick[found].mean()) if found.any() else None,
        "mean_explored_fraction": float(explored.mean()),
        "world_ticks": ticks,
        "world_ticks_per_s": ticks / dt,
    }


def render_episode(preset: str, seed: int, path: Path, max_frames: int = 200) -> Path:
    env = search_rescue_v0.parallel_env(preset=preset, level="primitive", render_mode="rgb_array")
    env.reset(seed=seed, options={"episode_index": 0})
    rng = np.random.default_rng(seed)
    frames = [env.render()]
    while env.agents and len(frames) < max_frames:
        acts = random_walk(rng, (len(env.agents),))
        env.step(dict(zip(env.agents, acts.tolist())))
        frames.append(env.render())
    return save_gif(frames, path, fps=12)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", default="task1", help="task1 | task2 | task3 | train")
    ap.add_argument("--episodes", type=int, default=64)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="out/demo")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stats = run_batch(args.preset, args.episodes, args.seed)
    gif = render_episode(args.preset, args.seed, out / "episode.gif")
    tmp = out / "stats.json.tmp"
    tmp.write_text(json.dumps(stats, indent=2))
    tmp.replace(out / "stats.json")
    print(f"\n{stats['episodes']} episodes of {stats['preset']} ({stats['policy']}):")
    for key in ("success_rate", "mean_rescue_tick", "target_found_rate", "mean_target_found_tick"):
        v = stats[key]
        print(f"  {key:<24} {'-' if v is None else f'{v:.3f}'}")
    print(f"  {'mean_explored_fraction':<24} {stats['mean_explored_fraction']:.3f}")
    print(f"  {'world_ticks_per_s':<24} {stats['world_ticks_per_s']:,.0f}")
    print(f"wrote {out / 'stats.json'} and {gif}")
    return stats


if __name__ == "__main__":
    main()
