"""Macro level: PettingZoo's battery (unmodified), TorchRL's check_env_specs, and the contract."""

import functools
from types import SimpleNamespace

import numpy as np
import pytest
from pettingzoo.test import (
    api_test,
    max_cycles_test,
    parallel_api_test,
    parallel_seed_test,
    render_test,
    seed_test,
)

from catmip_env import search_rescue_v0

PRESETS = ["task1", "task2", "task3", "train"]
VARIANTS = {"full": {}, "partial+noise": {"comm_sigma": 2.0, "slam_noise": 0.05}}


@pytest.mark.parametrize("preset", PRESETS)
@pytest.mark.parametrize("goal_mode", ["window", "cell"])
@pytest.mark.parametrize("variant", list(VARIANTS))
def test_pettingzoo_battery(preset, goal_mode, variant):
    kw = dict(preset=preset, goal_mode=goal_mode, **VARIANTS[variant])
    parallel_api_test(search_rescue_v0.parallel_env(**kw), num_cycles=300)
    # PettingZoo's seed tests sample actions without the mask: masked goals become "stay"
    parallel_seed_test(lambda: search_rescue_v0.parallel_env(invalid_action="stay", **kw), num_cycles=150)
    api_test(search_rescue_v0.env(**kw), num_cycles=100)
    seed_test(lambda: search_rescue_v0.env(**kw), num_cycles=100)


def test_max_cycles_and_render():
    macro = SimpleNamespace(
        parallel_env=functools.partial(search_rescue_v0.parallel_env, preset="task1", invalid_action="stay"),
        env=functools.partial(search_rescue_v0.env, preset="task1", invalid_action="stay"),
    )
    max_cycles_test(macro)
    render_test(lambda render_mode=None: search_rescue_v0.env(preset="task1", render_mode=render_mode))


@pytest.mark.parametrize("kw", [{}, {"comm_sigma": 2.0, "slam_noise": 0.05, "goal_mode": "cell"}])
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
            acts = {a: int(np.flatnonzero(o1[a]["action_mask"])[rng.integers(o1[a]["action_mask"].sum())])
                    for a in e1.agents}  # fmt: skip
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
    for a in env.possible_agents:
        assert set(infos[a]) == {"active", "agent_class", "event_ticks", "tick", "neighbourhood"}
        assert infos[a]["active"] == 1 and infos[a]["tick"] == 0 and infos[a]["event_ticks"] == 0
        assert "heading" not in obs[a]["observation"]
        assert env.observation_space(a).contains(obs[a])
    ticks = 0
    rng = np.random.default_rng(1)
    while env.agents:
        acts = {}
        for a in env.agents:
            if infos[a]["active"]:
                acts[a] = int(rng.choice(np.flatnonzero(obs[a]["action_mask"])))
            else:
                assert obs[a]["action_mask"].sum() == 1 and obs[a]["action_mask"][24] == 1
        obs, rewards, terms, truncs, infos = env.step(acts)  # busy robots may be omitted
        ticks += infos["robot_0"]["event_ticks"]
        assert infos["robot_0"]["event_ticks"] >= 1
        assert any(infos[a]["active"] for a in env.possible_agents) or terms["robot_0"] or truncs["robot_0"]
        assert len(set(terms.values())) == 1 and len(set(truncs.values())) == 1
    assert ticks == infos["robot_0"]["tick"]


def test_macro_errors():
    env = search_rescue_v0.parallel_env(preset="task1")
    obs, _ = env.reset(seed=0)
    masked = int(np.flatnonzero(obs["robot_1"]["action_mask"] == 0)[0])
    with pytest.raises(ValueError, match=r"missing actions for active robots \['robot_1'\]"):
        env.step({"robot_0": 24})
    with pytest.raises(ValueError, match="action 49 of robot_0 is out of range"):
        env.step({"robot_0": 49, "robot_1": 24})
    with pytest.raises(ValueError, match="robot_1 .*masked"):
        env.step({"robot_0": 24, "robot_1": masked})
    with pytest.raises(ValueError, match="unknown robot id"):
        env.step({"robot_0": 24, "robot_1": 24, "robot_5": 0})
    with pytest.raises(ValueError, match="goal_mode"):
        search_rescue_v0.parallel_env(goal_mode="polar")
    with pytest.raises(ValueError, match="invalid_action"):
        search_rescue_v0.parallel_env(invalid_action="ignore")
    lenient = search_rescue_v0.parallel_env(preset="task1", invalid_action="stay", max_cycles=2)
    lenient.reset(seed=0)
    lenient.step({"robot_0": 0, "robot_1": 0})
    _, _, _, truncs, _ = lenient.step({a: 24 for a in lenient.agents})
    assert all(truncs.values()) and lenient.agents == []
    with pytest.raises(RuntimeError, match="episode ended"):
        lenient.step({"robot_0": 24, "robot_1": 24})
