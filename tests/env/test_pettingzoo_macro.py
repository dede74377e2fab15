"""Macro level: PettingZoo's battery (unmodified, default envs), TorchRL's check_env_specs, the contract."""

import numpy as np
import pytest
from pettingzoo.test import (
    api_test,
    max_cycles_test,
    parallel_api_test,
    parallel_seed_test,
    performance_benchmark,
    render_test,
    seed_test,
    state_test,
)

from catmip_env import PRESETS, search_rescue_v0
from tests.env.helpers import turns_per_second

from .helpers import (
    COMM_NOISE,
    HUGE_INTEGERS,
    INVALID_FLAGS,
    NOT_INTEGERS,
    masked_random_action,
    pettingzoo_battery,
)


def test_default_env_passes_pettingzoo_tests_unmodified():
    """The module as a user finds it: default constructors, PettingZoo's default cycle counts."""
    parallel_api_test(search_rescue_v0.parallel_env())
    parallel_seed_test(search_rescue_v0.parallel_env)
    api_test(search_rescue_v0.env())
    seed_test(search_rescue_v0.env)
    max_cycles_test(search_rescue_v0)
    render_test(search_rescue_v0.env)
    state_test(search_rescue_v0.env(), search_rescue_v0.parallel_env())


@pytest.mark.parametrize("preset", sorted(PRESETS))
@pytest.mark.parametrize("goal_mode", ["window", "cell"])
@pytest.mark.parametrize("variant", list(COMM_NOISE))
def test_pettingzoo_battery(preset, goal_mode, variant):
    pettingzoo_battery(preset=preset, goal_mode=goal_mode, **COMM_NOISE[variant])


@pytest.mark.parametrize("preset", sorted(PRESETS))
@pytest.mark.parametrize("goal_mode", ["window", "cell"])
def test_pettingzoo_battery_flat(preset, goal_mode):
    kw = dict(preset=preset, goal_mode=goal_mode, obs_format="flat")
    pettingzoo_battery(**kw, **COMM_NOISE["comm+noise"])
    render_test(lambda render_mode=None: search_rescue_v0.env(render_mode=render_mode, **kw))


@pytest.mark.slow
def test_performance_benchmark_runs(capsys):
    performance_benchmark(search_rescue_v0.env())  # 5 s of random masked play; prints turns per second
    assert turns_per_second(capsys.readouterr().out) > 10


@pytest.mark.parametrize(
    "kw", [{}, {"comm_sigma": 2.0, "slam_noise": 0.05, "goal_mode": "cell"}, {"obs_format": "flat"}]
)
def test_torchrl_check_env_specs(kw):
    from torchrl.envs.libs.pettingzoo import PettingZooWrapper
    from torchrl.envs.utils import MarlGroupMapType, check_env_specs

    env = search_rescue_v0.parallel_env(preset="task1", **kw)
    wrapped = PettingZooWrapper(
        env, group_map=MarlGroupMapType.ALL_IN_ONE_GROUP, use_mask=True, categorical_actions=True
    )
    check_env_specs(wrapped, seed=0)
    td = wrapped.rollout(20)
    assert td["agents", "action_mask"].shape[-1] == env.num_actions
    assert td["next", "agents", "info", "active"].shape == (td.batch_size[0], 2)
    assert td["next", "agents", "info", "invalid_actions"].sum() == 0  # the rollout samples masked


def test_full_episode_determinism():
    for kw in ({}, {"comm_sigma": 2.0, "slam_noise": 0.05, "activation": (2, 5), "goal_mode": "cell"}):
        e1 = search_rescue_v0.parallel_env(preset="task2", **kw)
        e2 = search_rescue_v0.parallel_env(preset="task2", **kw)
        o1, i1 = e1.reset(seed=21)
        o2, i2 = e2.reset(seed=21)
        rng = np.random.default_rng(0)
        while e1.agents:
            _assert_same(o1, o2)
            assert i1 == i2 and e1.agents == e2.agents
            acts = {a: masked_random_action(rng, o1[a]["action_mask"]) for a in e1.agents}
            o1, r1, t1, u1, i1 = e1.step(acts)
            o2, r2, t2, u2, i2 = e2.step(acts)
            assert r1 == r2 and t1 == t2 and u1 == u2
        assert not e2.agents


def _assert_same(a, b):
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for k in a:
            _assert_same(a[k], b[k])
    else:
        assert np.array_equal(a, b)


def test_macro_contract():
    env = search_rescue_v0.parallel_env(preset="task2")
    obs, infos = env.reset(seed=0)
    assert env.level == "macro" and env.action_space("robot_0").n == 49
    assert env.invalid_action == "stay" and env.obs_format == "dict"
    keys = {"active", "agent_class", "event_ticks", "tick", "neighbourhood"} | INVALID_FLAGS
    for a in env.possible_agents:
        assert set(infos[a]) == keys
        assert infos[a]["active"] == 1 and infos[a]["tick"] == 0 and infos[a]["event_ticks"] == 0
        assert "heading" not in obs[a]["observation"]
        assert env.observation_space(a).contains(obs[a])
    ticks = 0
    rng = np.random.default_rng(1)
    while env.agents:
        acts = {}
        for a in env.agents:
            if infos[a]["active"]:
                acts[a] = masked_random_action(rng, obs[a]["action_mask"])
            else:
                assert obs[a]["action_mask"].sum() == 1 and obs[a]["action_mask"][24] == 1
        obs, rewards, terms, truncs, infos = env.step(acts)  # busy robots may be omitted
        ticks += infos["robot_0"]["event_ticks"]
        assert infos["robot_0"]["event_ticks"] >= 1
        assert any(infos[a]["active"] for a in env.possible_agents) or terms["robot_0"] or truncs["robot_0"]
        assert len(set(terms.values())) == 1 and len(set(truncs.values())) == 1
        assert all(infos[a]["invalid_actions"] == 0 for a in env.possible_agents)
    assert ticks == infos["robot_0"]["tick"]


def test_space_dicts():
    env = search_rescue_v0.parallel_env(preset="task3", goal_mode="cell")
    assert list(env.observation_spaces) == list(env.action_spaces) == env.possible_agents
    for a in env.possible_agents:
        assert env.observation_spaces[a] is env.observation_space(a)
        assert env.action_spaces[a] is env.action_space(a) and env.action_space(a).n == 32 * 32
    assert env.observation_space("robot_0") is not env.observation_space("robot_1")  # seeded one by one
    aec = search_rescue_v0.env(preset="task3")
    assert aec.unwrapped.observation_spaces["robot_5"] is aec.observation_space("robot_5")


def _first_masked(mask: np.ndarray) -> int:
    return int(np.flatnonzero(mask == 0)[0])


def _without_flags(info: dict) -> dict:
    return {k: v for k, v in info.items() if k not in INVALID_FLAGS}


def test_invalid_actions_become_stay_and_are_flagged():
    """Default policy: a masked or out-of-range goal plays exactly as "stay here" and is reported."""
    lenient = search_rescue_v0.parallel_env(preset="task1")
    reference = search_rescue_v0.parallel_env(preset="task1")
    obs, _ = lenient.reset(seed=0)
    reference.reset(seed=0)
    bad = {"robot_0": 49, "robot_1": _first_masked(obs["robot_1"]["action_mask"])}
    o1, r1, t1, u1, i1 = lenient.step(bad)
    o2, r2, t2, u2, i2 = reference.step({"robot_0": 24, "robot_1": 24})
    _assert_same(o1, o2)
    assert (r1, t1, u1) == (r2, t2, u2)
    for a in lenient.possible_agents:
        assert i1[a]["invalid_action"] == 1 and i1[a]["invalid_actions"] == 1
        assert i2[a]["invalid_action"] == 0 and i2[a]["invalid_actions"] == 0
        assert _without_flags(i1[a]) == _without_flags(i2[a])
    _, _, _, _, infos = lenient.step({a: 24 for a in lenient.agents})
    assert all(infos[a]["invalid_action"] == 0 and infos[a]["invalid_actions"] == 1 for a in lenient.agents)
    lenient.reset()
    _, _, _, _, infos = lenient.step({"robot_0": 24, "robot_1": 24})
    assert all(infos[a]["invalid_actions"] == 0 for a in lenient.possible_agents)  # counted per episode


@pytest.mark.parametrize("invalid_action", ["stay", "raise"])
def test_busy_robots_actions_are_ignored_not_flagged(invalid_action):
    env = search_rescue_v0.parallel_env(preset="train", invalid_action=invalid_action)
    obs, infos = env.reset(seed=3)
    rng = np.random.default_rng(0)
    checked = 0
    while env.agents:
        acts = {a: masked_random_action(rng, obs[a]["action_mask"]) for a in env.agents}
        busy = [a for a in env.agents if not infos[a]["active"]]
        for k, a in enumerate(busy):  # masked, out of range, or too large for an int64: all ignored
            acts[a] = [_first_masked(obs[a]["action_mask"]), -1, 2**63][(checked + k) % 3]
        obs, _, _, _, infos = env.step(acts)
        checked += len(busy)
        assert all(infos[a]["invalid_actions"] == 0 for a in env.possible_agents)
    assert checked > 0


@pytest.mark.parametrize("invalid_action", ["stay", "raise"])
@pytest.mark.parametrize("action", NOT_INTEGERS)
def test_non_integer_actions_raise_in_both_modes(invalid_action, action):
    env = search_rescue_v0.parallel_env(preset="task1", invalid_action=invalid_action)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action of robot_1 must be an integer"):
        env.step({"robot_0": 24, "robot_1": action})


@pytest.mark.parametrize("action", HUGE_INTEGERS)
def test_huge_integer_actions_are_out_of_range_in_both_modes(action):
    lenient, reference = (search_rescue_v0.parallel_env(preset="task1") for _ in range(2))
    lenient.reset(seed=0)
    reference.reset(seed=0)
    o1, r1, _, _, i1 = lenient.step({"robot_0": action, "robot_1": 24})
    o2, r2, _, _, i2 = reference.step({"robot_0": 24, "robot_1": 24})
    _assert_same(o1, o2)
    assert r1 == r2 and [i1[a]["invalid_action"] for a in lenient.agents] == [1, 0]
    strict = search_rescue_v0.parallel_env(preset="task1", invalid_action="raise")
    strict.reset(seed=0)
    with pytest.raises(ValueError, match=rf"action {int(action)} of robot_0 is out of range: window actions"):
        strict.step({"robot_0": action, "robot_1": 24})
    _, _, _, _, infos = strict.step({"robot_0": 24, "robot_1": 24})  # the error left the env untouched
    assert infos["robot_0"]["invalid_actions"] == 0


@pytest.mark.parametrize("action", [24, np.int32(24), np.uint8(24), np.array(24), 24.0, np.float32(24.0)])
def test_integer_actions_of_any_type_work(action):
    env = search_rescue_v0.parallel_env(preset="task1", invalid_action="raise")
    env.reset(seed=0)
    _, _, _, _, infos = env.step({"robot_0": action, "robot_1": action})
    assert infos["robot_0"]["invalid_actions"] == 0


def test_strict_mode_and_errors():
    env = search_rescue_v0.parallel_env(preset="task1", invalid_action="raise")
    obs, _ = env.reset(seed=0)
    masked = _first_masked(obs["robot_1"]["action_mask"])
    with pytest.raises(ValueError, match=r"missing actions for active robots \['robot_1'\]"):
        env.step({"robot_0": 24})
    with pytest.raises(ValueError, match="action 49 of robot_0 .*is out of range: window actions are 0..48"):
        env.step({"robot_0": 49, "robot_1": 24})
    with pytest.raises(ValueError, match=rf"action {masked} of robot_1 .*is masked: its goal cell"):
        env.step({"robot_0": 24, "robot_1": masked})
    with pytest.raises(ValueError, match="unknown robot id"):
        env.step({"robot_0": 24, "robot_1": 24, "robot_5": 0})
    for not_a_dict in ([24, 24], None, (24, 24)):
        with pytest.raises(TypeError, match=r"actions must be a dict of robot id -> action \({'robot_0': 0"):
            env.step(not_a_dict)
    _, _, _, _, infos = env.step({"robot_0": 24, "robot_1": 24})  # the errors left the env untouched
    assert infos["robot_0"]["tick"] >= 1 and infos["robot_0"]["invalid_actions"] == 0
    for bad in ({"goal_mode": "polar"}, {"invalid_action": "ignore"}, {"obs_format": "tensor"}):
        with pytest.raises(ValueError, match=f"unknown {next(iter(bad))}"):
            search_rescue_v0.parallel_env(**bad)
    with pytest.raises(ValueError, match="compact_obs"):
        search_rescue_v0.parallel_env(compact_obs=True, obs_format="flat")
    short = search_rescue_v0.parallel_env(preset="task1", max_cycles=2)
    short.reset(seed=0)
    short.step({"robot_0": 0, "robot_1": 0})
    _, _, _, truncs, _ = short.step({a: 24 for a in short.agents})
    assert all(truncs.values()) and short.agents == []
    with pytest.raises(RuntimeError, match="episode ended"):
        short.step({"robot_0": 24, "robot_1": 24})


@pytest.mark.parametrize("level", ["macro", "primitive"])
def test_flat_observation_is_the_dict_observation_raveled(level):
    kw = dict(preset="train", level=level, comm_sigma=2.0)
    flat, nested = search_rescue_v0.parallel_env(obs_format="flat", **kw), search_rescue_v0.parallel_env(**kw)
    fo, fi = flat.reset(seed=4)
    do, di = nested.reset(seed=4)
    rng = np.random.default_rng(0)
    parts = ["global_map", "local_map", "agent_class"] + (["heading"] if level == "primitive" else [])
    assert list(flat.flat_layout) == parts
    for _ in range(30):
        if not flat.agents:
            break
        for a in flat.possible_agents:
            space = flat.observation_space(a)
            assert space.shape == (sum(s.stop - s.start for s, _ in flat.flat_layout.values()),)
            assert space.dtype == np.float32 and space.contains(fo[a])
            for key, (sl, shape) in flat.flat_layout.items():
                assert np.array_equal(fo[a][sl].reshape(shape), do[a]["observation"][key])
            assert np.array_equal(fi[a].pop("action_mask"), do[a]["action_mask"])
            assert fi[a] == di[a]
        acts = {a: masked_random_action(rng, do[a]["action_mask"]) for a in flat.agents}
        fo, _, _, _, fi = flat.step(acts)
        do, _, _, _, di = nested.step(acts)
