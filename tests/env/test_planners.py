"""Planning baselines: they finish Task 1 episodes and beat the random-window floor.

The rules: docs/design.md#planning-baselines.
"""

import numpy as np
import pytest

from catmip_env import EnvConfig, make_config
from catmip_env.engines.events import EventEngine
from catmip_env.planners.baselines import PLANNERS, make_planner

EPISODES = 24
SEED = 2024


def _run(name: str, preset="task1", episodes=EPISODES, seed=SEED, **overrides):
    eng = EventEngine(make_config(preset, **overrides), episodes, seed=seed, goal_mode="cell")
    planner = make_planner(name, seed=0)
    eng.reset()
    while not eng.state.done.all():
        eng.step(planner.act(eng))
    st = eng.state
    horizon = eng.cfg.horizon_ticks
    return st.rescue_tick.copy(), np.where(st.rescue_tick >= 0, st.rescue_tick, horizon).mean()


@pytest.fixture(scope="module")
def floor():
    return _run("random-rescue")


@pytest.mark.parametrize(
    "name",
    ["nearest", "utility", "rrt", "rrt-relay", "rrt-relay-coord", "nearest-relay", "apf", "random-frontier"],
)
def test_baseline_finishes_task1_and_beats_the_random_window_floor(name, floor):
    rescue, mean_tick = _run(name)
    floor_rescue, floor_mean = floor
    assert (rescue >= 0).mean() >= 0.95, f"{name} rescued only {(rescue >= 0).mean():.2f}"
    assert mean_tick < floor_mean, f"{name}: mean rescue tick {mean_tick:.1f} vs floor {floor_mean:.1f}"
    assert (rescue[rescue >= 0] <= 100).mean() > (floor_rescue[floor_rescue >= 0] <= 100).mean()


def test_planners_are_seeded_and_deterministic():
    for name in PLANNERS:
        a, _ = _run(name, episodes=4)
        b, _ = _run(name, episodes=4)
        assert np.array_equal(a, b), name


def test_rescuer_heads_for_the_target_once_known():
    lay = """
    ##########
    #0.......#
    #........#
    #1.....T.#
    ##########
    """
    cfg = EnvConfig(layout=lay, team=("rescuer", "explorer"), horizon_ticks=100, activation=(0, 0))
    eng = EventEngine(cfg, 1, seed=0, goal_mode="cell")
    eng.reset()
    assert eng.state.found_tick[0] == 0  # robot_1 sees the target at reset
    actions = make_planner("random-rescue", seed=0).act(eng)
    w = eng.shape[1]
    assert divmod(int(actions[0, 0]), w) == (3, 6)  # the reachable side of the target nearest to it
    while not eng.state.done[0]:
        eng.step(make_planner("random-rescue", seed=0).act(eng))
    assert eng.state.rescue_tick[0] > 0


def test_planner_errors():
    with pytest.raises(ValueError, match="unknown planner"):
        make_planner("dijkstra")
    eng = EventEngine(make_config("task1"), 1, seed=0)  # window mode
    eng.reset()
    with pytest.raises(ValueError, match="goal_mode='cell'"):
        make_planner("nearest").act(eng)


@pytest.mark.parametrize("name", sorted(PLANNERS))
def test_a_world_plays_alike_alone_and_in_a_batch(name):
    """A planner's draws are per world and episode: maps 0 .. 2 played alone give the episodes they
    give inside a batch of 8 (a leaderboard replay of a few maps checks an entry of 1,000)."""
    batch, _ = _run(name, episodes=8)
    alone, _ = _run(name, episodes=3)
    assert np.array_equal(batch[:3], alone), name
