"""Your own policy on the paper's protocol, end to end: a policy written against the PettingZoo env alone,
evaluated on the same maps as the planners, then compared with paired confidence intervals.

    python examples/evaluate_my_policy.py --task task1 --episodes 100 --out out/my_policy

The same from the command line (any file, anywhere; ``make_policy`` is the factory):

    catmip eval --task task1 --method greedy=py:examples/evaluate_my_policy.py:make_policy --out out/e/greedy
    catmip eval --task task1 --method nearest --out out/e/nearest
    catmip compare out/e --out out/e-compare

The policy below is a hand-written heuristic (each active robot heads for the allowed goal in its window
with the most unexplored cells around it, or, once the target is on its map, for the allowed goal
nearest the target); a learned policy plugs in the same way (docs/benchmark-your-algorithm.md).
"""

from __future__ import annotations

import argparse

import numpy as np


class GreedyFrontier:
    """PettingZoo-level policy: ``act(observations, infos) -> {robot: goal action}`` for the active robots.

    Reads only what ``search_rescue_v0.parallel_env(level="macro")`` gives: the robot's global map
    (channel 0 explored, 2 the target's 3x3 block at 1.0, the last channel its own 3x3 position block),
    the action mask, and ``infos[robot]["active"]``."""

    def __init__(self, window: int, seed: int) -> None:
        self.window = window
        self.rng = np.random.default_rng(seed)

    def reset(self) -> None:
        """Called before every episode (nothing to forget here)."""

    def act(self, observations: dict, infos: dict) -> dict:
        return {r: self._goal(o) for r, o in observations.items() if infos[r]["active"]}

    def _goal(self, obs: dict) -> int:
        g = obs["observation"]["global_map"]  # (5 + C, H, W) float32
        d, half = self.window, self.window // 2
        own = np.argwhere(g[-1] > 0).mean(0).round().astype(int)  # centre of the 3x3 position block
        cells = own + np.stack(np.divmod(np.arange(d * d), d), 1) - half  # (D*D, 2) window cells
        h, w = g.shape[1:]
        inside = (cells[:, 0] >= 0) & (cells[:, 0] < h) & (cells[:, 1] >= 0) & (cells[:, 1] < w)
        cells = np.clip(cells, 0, [h - 1, w - 1])
        target = np.argwhere(g[2] >= 1.0)
        if len(target):  # the target is on this robot's map: go next to it
            centre = target.mean(0)
            score = -np.abs(cells - centre).sum(1)
        else:  # the most unexplored cells in the 3x3 around the goal
            unexplored = np.pad(1.0 - g[0], 1)
            score = sum(
                unexplored[cells[:, 0] + 1 + dr, cells[:, 1] + 1 + dc]
                for dr in (-1, 0, 1)
                for dc in (-1, 0, 1)
            )
        score = score + self.rng.random(len(score)) * 1e-3  # random tie-break
        score[(obs["action_mask"] == 0) | ~inside] = -np.inf
        return int(np.argmax(score))


def make_policy(env_config, seed: int) -> GreedyFrontier:
    """The factory ``catmip eval --method NAME=py:FILE.py:make_policy`` calls: the evaluation's
    ``EnvConfig`` (task, communication, goal window ...) and a seed for the policy's own stream (0 on
    every map set). Every episode is played by a fresh copy of what it returns, so its tie-breaking
    stream starts anew on each map, and any map replays alone."""
    return GreedyFrontier(env_config.window, seed)


def main(argv: list[str] | None = None) -> dict[str, float]:
    from catmip_rl.benchmark.compare import compare
    from catmip_rl.benchmark.results import load_results
    from catmip_rl.evaluation.evaluate import EvalSetting, evaluate

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="task1", choices=["task1", "task2", "task3"])
    ap.add_argument("--comm", default="full", help="full | 4 | 2")
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0, help="the map set")
    ap.add_argument("--out", default="out/my_policy")
    args = ap.parse_args(argv)

    setting = EvalSetting(args.task, args.comm)
    policy = make_policy(setting.env_config(), args.seed)
    runs = {
        "greedy": evaluate("greedy", setting, args.episodes, args.seed, policy=policy),
        "nearest": evaluate("nearest", setting, args.episodes, args.seed),
        "random-uniform": evaluate("random-uniform", setting, args.episodes, args.seed),
    }
    hashes = {name: [e["map_hash"] for e in r.episodes] for name, r in runs.items()}
    assert hashes["greedy"] == hashes["nearest"] == hashes["random-uniform"], (
        "every method plays the same maps"
    )
    for name, r in runs.items():
        r.write(f"{args.out}/eval/{name}")
    report = compare(load_results([f"{args.out}/eval"]))
    report.write(f"{args.out}/compare")
    print(report.markdown())
    print(f"maps: {runs['greedy'].summary['map_set']} {runs['greedy'].summary['map_set_status']}")
    return {name: r.summary["success_by_100"] for name, r in runs.items()}


if __name__ == "__main__":
    main()
