"""The ``py:`` policies ``bench_isolation.py`` times in-process and isolated: two at the engine level, one
at a planner's speed and one at AMAT's, and one at the PettingZoo level.

    catmip eval --task task2 --comm 2 --method py:benchmarks/isolation_policies.py:planner
"""

from __future__ import annotations

import numpy as np

from catmip_env.planners import make_planner

AMAT_MODEL = "paper"  # the shipped catmip_rl/models/amat_paper.pt, by name (the worker runs elsewhere)


class Planner:
    """Engine level, a planner's speed: the nearest-frontier planner, cell goals."""

    goal_mode = "cell"

    def __init__(self, seed: int) -> None:
        self.planner = make_planner("nearest", seed=seed)

    def act(self, engine):
        return self.planner.act(engine)


class Amat:
    """Engine level, AMAT's speed: the shipped paper model through catmip_rl's executor (what
    ``--method amat:paper`` plays), window goals."""

    goal_mode = "window"

    def __init__(self, env_config, seed: int) -> None:
        from catmip_rl.evaluation.methods import make_policy, parse_method

        self.executor, self.goal_mode, _needs = make_policy(
            parse_method(f"amat:{AMAT_MODEL}"), env_config, seed
        )

    def act(self, engine):
        return self.executor.act(engine)


class FirstAllowed:
    """PettingZoo level: each active robot's first allowed goal, read from its action mask."""

    def act(self, observations, infos):
        return {r: int(np.argmax(o["action_mask"])) for r, o in observations.items() if infos[r]["active"]}


def planner(env_config, seed):
    return Planner(seed)


def amat(env_config, seed):
    return Amat(env_config, seed)


def first_allowed(env_config, seed):
    return FirstAllowed()
