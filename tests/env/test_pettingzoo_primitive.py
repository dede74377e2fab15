"""Primitive level: PettingZoo conformance (the library's own battery, unmodified) and the contract."""

import functools
import re
import subprocess
import sys

import numpy as np
import pettingzoo
import pytest
from pettingzoo.test import performance_benchmark, render_test

import catmip_env
from catmip_env import PRESETS, search_rescue_v0
from tests.env.helpers import turns_per_second

from .helpers import COMM_NOISE, HUGE_INTEGERS, INVALID_FLAGS, NOT_INTEGERS, pettingzoo_battery

prim_parallel_env = functools.partial(search_rescue_v0.parallel_env, level="primitive")
prim_env = functools.partial(search_rescue_v0.env, level="primitive")


@pytest.mark.parametrize("preset", sorted(PRESETS))
@pytest.mark.parametrize("variant", list(COMM_NOISE))
@pytest.mark.parametrize("obs_format", ["dict", "flat"])
def test_pettingzoo_battery(preset, variant, obs_format):
    pettingzoo_battery(level="primitive", preset=preset, obs_format=obs_format, **COMM_NOISE[variant])


@pytest.mark.parametrize("obs_format", ["dict", "flat"])
def test_render(obs_format):
    render_test(lambda render_mode=None: prim_env(render_mode=render_mode, obs_format=obs_format))


@pytest.mark.slow
def test_performance_benchmark_runs(capsys):
    performance_benchmark(prim_env())  # 5 s of random play; prints turns per second
    assert turns_per_second(capsys.readouterr().out) > 10


def test_full_episode_determinism():
    """Two envs, same seed, same random actions: identical everything until the episode ends."""
    for kw in ({}, {"comm_sigma": 2.0, "slam_noise": 0.05}):
        e1 = prim_parallel_env(preset="task2", **kw)
        e2 = prim_parallel_env(preset="task2", **kw)
        for episode in range(2):
            seed = 11 if episode == 0 else None
            o1, i1 = e1.reset(seed=seed)
            o2, i2 = e2.reset(seed=seed)
            rng = np.random.default_rng(episode)
            steps = 0
            while e1.agents:
                assert e1.agents == e2.agents
                _assert_same(o1, o2)
                assert i1 == i2
                assert np.array_equal(e1.state(), e2.state())
                acts = {a: int(rng.integers(4)) for a in e1.agents}
                o1, r1, t1, u1, i1 = e1.step(acts)
                o2, r2, t2, u2, i2 = e2.step(acts)
                assert r1 == r2 and t1 == t2 and u1 == u2
                steps += 1
            assert not e2.agents and steps == e1.engine.state.ticks[0]


def test_reset_seed_replays_and_episodes_differ():
    env = prim_parallel_env(preset="task1")
    env.reset(seed=3)
    first = env.state().copy()
    env.reset()
    second = env.state().copy()
    env.reset(seed=3)
    assert np.array_equal(env.state(), first)
    assert not np.array_equal(first, second)
    env.reset(options={"episode_index": 1})
    assert np.array_equal(env.state(), second)


def _assert_same(a, b):
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for k in a:
            _assert_same(a[k], b[k])
    else:
        assert np.array_equal(a, b)


def test_observation_contract():
    env = prim_parallel_env(preset="task3")
    obs, infos = env.reset(seed=0)
    c, s = env.config.num_classes, env.config.map_size
    for agent in env.possible_agents:
        o = obs[agent]
        assert env.observation_space(agent).contains(o)
        assert o["observation"]["global_map"].shape == (5 + c, s, s)
        assert o["observation"]["local_map"].shape == (4 + c, 7, 7)
        assert o["observation"]["global_map"].dtype == np.float32
        assert set(np.unique(o["observation"]["global_map"])) <= {0.0, 0.25, 1.0}
        assert o["action_mask"].dtype == np.int8 and o["action_mask"].tolist() == [1, 1, 1, 1]
        cls = infos[agent]["agent_class"]
        assert o["observation"]["agent_class"].tolist() == np.eye(c)[cls].tolist()
        assert set(infos[agent]) == {"agent_class", "tick", "neighbourhood", "can_act", "knows_target"} | (
            INVALID_FLAGS
        )
    assert env.state().shape == env.state_space.shape
    compact = prim_parallel_env(preset="task3", compact_obs=True)
    co, _ = compact.reset(seed=0)
    g = co["robot_0"]["observation"]["global_map"]
    assert g.dtype == np.uint8
    assert np.array_equal(g * 0.25, obs["robot_0"]["observation"]["global_map"])


def test_rescuer_can_act_flag():
    env = prim_parallel_env(preset="task1")
    _, infos = env.reset(seed=0)
    flags = []
    for _ in range(4):
        flags.append(infos["robot_0"]["can_act"])
        _, _, _, _, infos = env.step({a: 3 for a in env.agents})
    assert flags == [1, 0, 1, 0]  # robot_0 is the rescuer of task1
    assert infos["robot_1"]["can_act"] == 1


def test_out_of_range_actions_become_stay_and_are_flagged():
    lenient, reference = prim_parallel_env(preset="task1"), prim_parallel_env(preset="task1")
    lenient.reset(seed=0)
    reference.reset(seed=0)
    o1, r1, _, _, i1 = lenient.step({"robot_0": -1, "robot_1": 4})
    o2, r2, _, _, i2 = reference.step({"robot_0": 3, "robot_1": 3})
    _assert_same(o1, o2)
    assert r1 == r2 and np.array_equal(lenient.state(), reference.state())
    assert [i1[a]["invalid_action"] for a in lenient.agents] == [1, 1]
    assert [i2[a]["invalid_action"] for a in reference.agents] == [0, 0]
    _, _, _, _, i1 = lenient.step({"robot_0": 2, "robot_1": 7})
    assert [(i1[a]["invalid_action"], i1[a]["invalid_actions"]) for a in lenient.agents] == [(0, 1), (1, 2)]


@pytest.mark.parametrize("action", HUGE_INTEGERS)
def test_huge_integer_actions_are_out_of_range_in_both_modes(action):
    lenient, reference = prim_parallel_env(preset="task1"), prim_parallel_env(preset="task1")
    lenient.reset(seed=0)
    reference.reset(seed=0)
    o1, r1, _, _, i1 = lenient.step({"robot_0": 2, "robot_1": action})
    o2, r2, _, _, i2 = reference.step({"robot_0": 2, "robot_1": 3})
    _assert_same(o1, o2)
    assert r1 == r2 and np.array_equal(lenient.state(), reference.state())
    assert [i1[a]["invalid_action"] for a in lenient.agents] == [0, 1]
    strict = prim_parallel_env(preset="task1", invalid_action="raise")
    strict.reset(seed=0)
    with pytest.raises(
        ValueError, match=rf"action {int(action)} of robot_1 is out of range: primitive actions"
    ):
        strict.step({"robot_0": 2, "robot_1": action})


@pytest.mark.parametrize("invalid_action", ["stay", "raise"])
@pytest.mark.parametrize("action", NOT_INTEGERS)
def test_non_integer_actions_raise_in_both_modes(invalid_action, action):
    env = prim_parallel_env(preset="task1", invalid_action=invalid_action)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action of robot_1 must be an integer"):
        env.step({"robot_0": 3, "robot_1": action})


def test_bad_input_raises_clear_errors():
    env = prim_parallel_env(preset="task1", horizon_ticks=3, invalid_action="raise")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="unknown robot id 'robot_7'"):
        env.step({"robot_0": 0, "robot_1": 0, "robot_7": 0})
    with pytest.raises(ValueError, match=r"action 9 of robot_1 is out of range: primitive actions are 0..3"):
        env.step({"robot_0": 0, "robot_1": 9})
    with pytest.raises(ValueError, match=r"missing actions for robots \['robot_1'\]"):
        env.step({"robot_0": 0})
    for not_a_dict, name in (([0, 0], "list"), (None, "NoneType"), (np.zeros(2, np.int64), "ndarray")):
        with pytest.raises(TypeError, match=f"actions must be a dict of robot id -> action .*, got {name}$"):
            env.step(not_a_dict)
    with pytest.raises(ValueError, match="unknown robot id"):
        env.action_space("robot_9")
    with pytest.raises(ValueError, match="unknown level"):
        search_rescue_v0.parallel_env(level="nano")
    with pytest.raises(ValueError, match="render_mode"):
        prim_parallel_env(render_mode="svg")
    for _ in range(3):
        env.step({"robot_0": 3, "robot_1": 3})
    assert env.agents == []
    with pytest.raises(RuntimeError, match="episode ended"):
        env.step({"robot_0": 3, "robot_1": 3})


@pytest.mark.parametrize("level", ["primitive", "macro"])
@pytest.mark.parametrize("episode", [2**70, 2**63, 2**62, -1, 1.5, True, "3", None])
def test_a_bad_episode_index_is_refused_naming_it(level, episode):
    env = search_rescue_v0.parallel_env(preset="task1", level=level)
    wanted = rf'options\["episode_index"\] must be an int in \[0, 2\*\*62\), got {re.escape(repr(episode))}$'
    with pytest.raises(ValueError, match=wanted):
        env.reset(seed=0, options={"episode_index": episode})
    env.reset(seed=0, options={"episode_index": np.int64(2**62 - 1)})  # the largest one plays
    assert env.unwrapped.world.state.episode[0] == 2**62 - 1


def test_registry():
    par = pettingzoo.make("parallel", "catmip/SearchRescue-v0", preset="task1", comm_sigma=4.0)
    assert par.level == "macro"
    assert par.config.comm_sigma == 4.0
    aec = pettingzoo.make("aec", "catmip/SearchRescue-v0", preset="task1", level="primitive", max_cycles=7)
    aec.reset(seed=0)
    assert aec.unwrapped.config.horizon_ticks == 7  # PettingZoo's max_cycles -> horizon_ticks


def test_render_modes(tmp_path):
    env = prim_parallel_env(preset="task1", render_mode="rgb_array")
    env.reset(seed=0)
    frames = [env.render()]
    for _ in range(5):
        env.step({a: 2 for a in env.agents})
        frames.append(env.render())
    f = frames[-1]
    assert f.dtype == np.uint8 and f.shape == (15 * 16, 15 * 16, 3)
    from catmip_env.envs.render import save_gif

    path = save_gif(frames, tmp_path / "ep.gif")
    assert path.stat().st_size > 1000
    text = prim_parallel_env(preset="task1", render_mode="ansi")
    text.reset(seed=0)
    assert len(text.render().splitlines()) == 15


def test_import_does_not_pull_torch():
    code = "import sys, catmip_env, catmip_env.envs.search_rescue_v0; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
    assert catmip_env.__version__
