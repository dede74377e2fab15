"""A random policy on the PettingZoo Parallel env: the loop every MARL library runs.

python examples/pettingzoo_quickstart.py [--preset task2] [--episodes 2] [--no-mask]

Only robots with ``infos[robot]["active"] == 1`` decide; the others' actions are ignored (their mask
allows just "keep your goal"). With ``--no-mask`` the policy ignores the mask: each invalid goal plays
as "stay here" and is counted in ``infos[robot]["invalid_actions"]`` (docs/quickstart.md).
"""

from __future__ import annotations

import argparse

import numpy as np

from catmip_env import search_rescue_v0


def main(argv: list[str] | None = None) -> list[dict[str, float]]:
    """Play random episodes; one summary per episode (team return, ticks, decisions, invalid goals)."""
    ap = argparse.ArgumentParser()
    ap.add_argument("--preset", default="task2")
    ap.add_argument("--episodes", type=int, default=2)
    ap.add_argument("--comm-sigma", type=float, default=None, help="None = full communication")
    ap.add_argument("--no-mask", action="store_true", help="sample goals without the action mask")
    ap.add_argument("--seed", type=int, default=0, help="seed of the maps and of the random goals")
    args = ap.parse_args(argv)

    env = search_rescue_v0.parallel_env(preset=args.preset, comm_sigma=args.comm_sigma)
    episodes = []
    for episode in range(args.episodes):
        obs, infos = env.reset(seed=args.seed + episode)
        for k, robot in enumerate(env.agents):  # the random goals are seeded too: a run repeats exactly
            env.action_space(robot).seed(args.seed + 1000 * episode + k)
        total, decisions = 0.0, 0
        while env.agents:
            deciding = [robot for robot in env.agents if infos[robot]["active"]]
            masks = {robot: None if args.no_mask else obs[robot]["action_mask"] for robot in deciding}
            actions = {robot: env.action_space(robot).sample(mask=masks[robot]) for robot in deciding}
            obs, rewards, terminations, truncations, infos = env.step(actions)
            total += sum(rewards.values())
            decisions += len(deciding)
        state = env.unwrapped.engine.state
        invalid = sum(info["invalid_actions"] for info in infos.values())
        print(
            f"episode {episode}: team return {total:8.2f}, ticks {int(state.ticks[0])}, "
            f"target found at {int(state.found_tick[0])}, rescued at {int(state.rescue_tick[0])}, "
            f"{decisions} decisions ({invalid} invalid, played as stay)"
        )
        episodes.append(
            {"return": total, "ticks": int(state.ticks[0]), "decisions": decisions, "invalid": invalid}
        )
    print(f"mean team return {np.mean([e['return'] for e in episodes]):.2f}")
    return episodes


if __name__ == "__main__":
    main()
