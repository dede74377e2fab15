"""SuperSuit on the flat observation format: the common wrappers and a CleanRL-style vector pipeline."""

import numpy as np
import pytest
import supersuit as ss

from catmip_env import search_rescue_v0

from .helpers import masked_random_action

STEPS = 300


def flat_env(level: str = "macro", **kw):
    return search_rescue_v0.parallel_env(preset="task1", level=level, obs_format="flat", comm_sigma=4.0, **kw)


def play_beside(wrapped, check, steps: int = STEPS) -> int:
    """Random masked play of ``wrapped`` and of a bare twin (same seed, same actions); ``check(robot, obs,
    raw, prev_raw)`` compares its wrapped and raw (this and the previous step) observations. Returns the
    number of episodes ended."""
    raw_env = flat_env(wrapped.unwrapped.level)
    obs, infos = wrapped.reset(seed=0)
    raw, _ = raw_env.reset(seed=0)
    prev = dict.fromkeys(raw)
    rng = np.random.default_rng(0)
    ended = 0
    for _ in range(steps):
        assert wrapped.agents == raw_env.agents == raw_env.possible_agents  # nobody leaves early
        for a in wrapped.agents:
            assert wrapped.observation_space(a).contains(obs[a])
            check(a, obs[a], raw[a], prev[a])
        actions = {a: masked_random_action(rng, infos[a]["action_mask"]) for a in wrapped.agents}
        prev = raw
        obs, _, terms, truncs, infos = wrapped.step(actions)
        raw, _, _, _, _ = raw_env.step(actions)
        if not wrapped.unwrapped.agents:  # see test_black_death for why not ``wrapped.agents``
            ended += 1
            obs, infos = wrapped.reset()
            raw, _ = raw_env.reset()
            prev = dict.fromkeys(raw)
    return ended


@pytest.mark.parametrize("level", ["macro", "primitive"])
def test_flatten_and_normalize_obs(level):
    env = flat_env(level)
    size = env.observation_space("robot_0").shape[0]
    flat = ss.flatten_v0(flat_env(level))
    assert flat.observation_space("robot_0").shape == (size,)
    assert play_beside(flat, lambda a, o, raw, prev: np.testing.assert_array_equal(o, raw)) > 0
    norm = ss.normalize_obs_v0(flat_env(level), env_min=-1.0, env_max=1.0)
    assert norm.observation_space("robot_0").shape == (size,)
    assert play_beside(norm, lambda a, o, raw, prev: np.testing.assert_allclose(o, 2 * raw - 1)) > 0


@pytest.mark.parametrize("level", ["macro", "primitive"])
def test_agent_indicator(level):
    env = ss.agent_indicator_v0(flat_env(level))
    n, size = len(env.possible_agents), flat_env(level).observation_space("robot_0").shape[0]
    assert env.observation_space("robot_1").shape == (size + n,)

    def check(agent, obs, raw, prev):
        np.testing.assert_array_equal(obs[:size], raw)
        assert obs[size:].tolist() == np.eye(n)[env.possible_agents.index(agent)].tolist()

    assert play_beside(env, check) > 0


@pytest.mark.parametrize("level", ["macro", "primitive"])
def test_frame_stack(level):
    env = ss.frame_stack_v1(flat_env(level), stack_size=3)
    size = flat_env(level).observation_space("robot_0").shape[0]
    assert env.observation_space("robot_0").shape == (3 * size,)

    def check(agent, obs, raw, prev):
        np.testing.assert_array_equal(obs[-size:], raw)  # newest frame last
        np.testing.assert_array_equal(obs[-2 * size : -size], 0 if prev is None else prev)

    assert play_beside(env, check) > 0


def test_black_death():
    """Nothing for it to do (no robot leaves before the others), and SuperSuit 3.11's black_death_v3 never
    reports the end of an episode: it requires every robot terminated *and* truncated (SuperSuit#254,
    fixed upstream by #265). Read the end from ``env.unwrapped.agents`` instead (docs/environment.md)."""
    env = ss.black_death_v3(flat_env())
    assert play_beside(env, lambda a, o, raw, prev: np.testing.assert_array_equal(o, raw)) > 0
    env.reset(seed=1)
    terms = truncs = {}
    while env.unwrapped.agents:
        _, _, terms, truncs, _ = env.step(dict.fromkeys(env.agents, 24))
    assert not any(terms.values()) and not any(truncs.values()) and env.agents  # the known bug
    with pytest.raises(RuntimeError, match="episode ended"):
        env.step(dict.fromkeys(env.agents, 24))


@pytest.mark.parametrize("level", ["macro", "primitive"])
@pytest.mark.parametrize("num_cpus", [0, 1])
def test_cleanrl_style_vector_pipeline(level, num_cpus):
    """CleanRL's PettingZoo recipe: every robot becomes one slot of a gymnasium vector env, reset on end."""
    env = ss.agent_indicator_v0(flat_env(level))
    envs = ss.concat_vec_envs_v1(ss.pettingzoo_env_to_vec_env_v1(env), 2, num_cpus=num_cpus)
    n = len(env.possible_agents)
    assert envs.num_envs == 2 * n and envs.action_space.n == env.action_space("robot_0").n
    obs, infos = envs.reset(seed=0)
    assert obs.shape == (2 * n, *env.observation_space("robot_0").shape) and obs.dtype == np.float32
    rng = np.random.default_rng(0)
    ended = 0
    for _ in range(STEPS):
        masks = np.stack([info["action_mask"] for info in infos])  # (2N, A)
        actions = np.array([masked_random_action(rng, m) for m in masks])
        obs, rewards, terms, truncs, infos = envs.step(actions)
        assert obs.shape[0] == rewards.shape[0] == terms.shape[0] == len(infos) == 2 * n
        assert np.isfinite(rewards).all()
        assert all(info["invalid_action"] == 0 for info in infos)
        done = terms | truncs
        assert (done.reshape(2, n).all(1) == done.reshape(2, n).any(1)).all()  # a team ends together
        for i in np.flatnonzero(done):  # auto-reset: the last observation rides in the info
            assert infos[i]["terminal_observation"].shape == obs.shape[1:]
        ended += int(done.reshape(2, n).all(1).sum())
    assert ended > 0
    envs.close()
