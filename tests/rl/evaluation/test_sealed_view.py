"""What a user's policy is told of the maps it plays: nothing that names them. Its factory gets the same
seed on every map set, the view has each world's key (not the map set's seed, not the episode index),
and a planner wrapped in a ``py:`` policy, keying its streams on the view's keys, still plays any one
map alone as it plays it in a batch (what a replay of chosen maps needs)."""

from __future__ import annotations

import textwrap

import pytest

from catmip_env.config import make_config
from catmip_env.engines.world import BatchedWorld, world_key
from catmip_rl.evaluation.evaluate import EvalSetting, evaluate
from catmip_rl.evaluation.methods import POLICY_SEED

SETTING = EvalSetting("task2", "2", 0.05)

WRAPS_A_PLANNER = textwrap.dedent(
    """
    from catmip_env.planners import make_planner

    SEEDS = []

    def make(env_config, seed):
        SEEDS.append(seed)
        if seed != 0:
            raise ValueError(f"told seed {seed}")
        planner = make_planner("random-frontier", seed=seed)
        planner.goal_mode = "cell"
        return planner
    """
)


@pytest.fixture
def wrapper(tmp_path):
    path = tmp_path / "wraps.py"
    path.write_text(WRAPS_A_PLANNER)
    return f"py:{path}:make"


def test_world_keys_are_per_map_and_name_neither_seed_nor_episode():
    world = BatchedWorld(make_config("task2"), num_worlds=3, seed=20261201)
    world.reset(episode_indices=[5, 0, 5])
    keys = world.world_keys.tolist()
    assert keys[0] == keys[2] == world_key(20261201, 5) and keys[1] == world_key(20261201, 0)
    assert keys[0] != keys[1] and all(0 <= k < 2**63 for k in keys)
    assert world_key(1000, 5) != keys[0]  # another map set: another key


@pytest.mark.parametrize("isolated", [False, True])
def test_a_factory_is_told_the_same_seed_on_every_map_set(wrapper, isolated):
    for seed in (1000, 20261201):  # the factory raises unless it is given POLICY_SEED
        evaluate(wrapper, SETTING, episodes=1, seed=seed, sampled_too=False, isolated=isolated)
    assert POLICY_SEED == 0


@pytest.mark.parametrize("isolated", [False, True])
def test_a_wrapped_planner_replays_chosen_maps_alone_as_in_the_batch(wrapper, isolated):
    batch = evaluate(wrapper, SETTING, episodes=12, seed=1000, sampled_too=False, isolated=isolated)
    picks = [9, 2, 11]
    alone = evaluate(wrapper, SETTING, seed=1000, sampled_too=False, isolated=isolated, episode_indices=picks)
    assert [e["episode"] for e in alone.episodes] == picks
    assert [e["map_hash"] for e in alone.episodes] == [batch.episodes[k]["map_hash"] for k in picks]
    assert [e["rescue_tick"] for e in alone.episodes] == [batch.episodes[k]["rescue_tick"] for k in picks]
    assert alone.summary["map_set_status"] == "verified"


def test_chosen_maps_of_a_frozen_set_are_checked_against_their_own_hashes():
    from catmip_env.maps.map_sets import MapSetMismatch, check_maps, manifest

    frozen = manifest("task2")["seeds"]["1000"]
    assert check_maps("task2", 1000, [frozen[700], frozen[3]], indices=[700, 3]).status == "verified"
    with pytest.raises(MapSetMismatch, match="map 3 of task2/seed1000"):
        check_maps("task2", 1000, [frozen[700], frozen[4]], indices=[700, 3])


@pytest.mark.parametrize("isolated", [False, True])
def test_a_pettingzoo_policy_with_its_own_stream_replays_any_map_alone(isolated):
    """The example's heuristic breaks ties from one random stream seeded by its factory: every map is
    played by a copy of the factory's policy, so a map played alone gets the tick it got in the run."""
    spec = "py:examples/evaluate_my_policy.py:make_policy"
    run = evaluate(spec, SETTING, episodes=6, seed=1000, sampled_too=False, isolated=isolated)
    alone = evaluate(spec, SETTING, seed=1000, sampled_too=False, isolated=isolated, episode_indices=[4, 1])
    assert [e["rescue_tick"] for e in alone.episodes] == [run.episodes[k]["rescue_tick"] for k in (4, 1)]


def test_an_uncopyable_pettingzoo_policy_is_one_line():
    import threading

    from catmip_rl.evaluation.user_policy import PolicyError

    class Locked:
        lock = None

        def __init__(self):
            self.lock = threading.Lock()

        def act(self, observations, infos):
            return {r: 0 for r in observations if infos[r]["active"]}

    with pytest.raises(PolicyError, match=r"cannot be copied .*\(copy.deepcopy\)"):
        evaluate("locked", SETTING, episodes=1, seed=1000, policy=Locked())
