"""A random policy on the PettingZoo Parallel env: the loop every MARL library runs.

python examples/pettingzoo_quickstart.py [--preset task2] [--episodes 2]
"""

from __future__ import annotations

import argparse

import numpy as np

from catmip_env import search_rescue_v0


def main(argv: list[str] | None = None) -> list[float]:
    ap = argparse.ArgumentParser()
    ap.add_argument("--preset", default="task2")
    ap.add_argument("--episodes", type=int, default=2)
    ap.add_argument("--comm-sigma", type=float, default=None, help="None = full communication")
    args = ap.parse_args(argv)

    env = search_rescue_v0.parallel_env(preset=args.preset, comm_sigma=args.comm_sigma)
    returns = []
    for episode in range(args.episodes):
        obs, infos = env.reset(seed=episode)
        total = 0.0
        while env.agents:
            actions = {
                robot: env.action_space(robot).sample(mask=obs[robot]["action_mask"]) for robot in env.agents
            }
            obs, rewards, terminations, truncations, infos = env.step(actions)
            total += sum(rewards.values())
        state = env.unwrapped.engine.state
        print(
            f"episode {episode}: team return {total:8.2f}, ticks {int(state.ticks[0])}, "
            f"target found at {int(state.found_tick[0])}, rescued at {int(state.rescue_tick[0])}"
        )
        returns.append(total)
    print(f"mean team return {np.mean(returns):.2f}")
    return returns


if __name__ == "__main__":
    main()
