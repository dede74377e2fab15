"""The TorchRL env over the event engine (``adapters.torchrl_env``): specs, resets, done keys, transforms."""

import pytest
import torch
from tensordict.nn import TensorDictModule
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import check_env_specs
from torchrl.objectives.value import GAE

from catmip_env.constants import OBS_SCALE
from catmip_rl.adapters import keys as K
from catmip_rl.adapters.torchrl_actor import AmatActor
from catmip_rl.adapters.torchrl_env import CatmipEnv, float_observation_transform
from catmip_rl.amat.model import AMAT


def test_env_passes_check_env_specs_and_runs_the_actor():
    env = CatmipEnv("train", num_worlds=4, seed=0)
    check_env_specs(env, seed=0)
    td = env.rollout(6, policy=AmatActor(AMAT()), break_when_any_done=False)
    assert td.batch_size == (4, 6)
    assert td["next", K.ROBOTS, "reward"].shape == (4, 6, 3, 1)
    assert td[K.GLOBAL_MAP].dtype == torch.uint8 and td[K.ACTION_MASK].dtype == torch.bool
    acts, mask = td[K.ACTION], td[K.ACTION_MASK]
    assert mask.gather(-1, acts[..., None]).all()
    assert (td["next", "event_ticks"] >= 1).all()


def test_step_without_a_tensordict_is_a_type_error_naming_the_action_key():
    env = CatmipEnv("task1", num_worlds=2, seed=0)
    env.reset()
    for not_a_tensordict, name in (([0, 0], "list"), (None, "NoneType"), ({"robot_0": 0}, "dict")):
        with pytest.raises(TypeError, match=rf"CatmipEnv.step takes a TensorDict .*'action'.*, got {name}$"):
            env.step(not_a_tensordict)


def test_env_partial_reset():
    env = CatmipEnv("task1", num_worlds=3, seed=1, horizon_ticks=5)
    td = env.reset()
    policy = AmatActor(AMAT())
    for _ in range(12):
        td = policy(td)
        td = env.step(td)
        done = td["next", "done"]
        td = env.step_mdp(td)
        if done.any():
            td.set("_reset", done)
            td = env.reset(td)
    assert not env.engine.state.done.all()


def test_group_level_done_flags_state_and_group_map():
    env = CatmipEnv("task1", num_worlds=3, seed=1, horizon_ticks=20)
    assert env.group_map == {"robots": ["robot_0", "robot_1"]}
    assert {"done", "terminated", "truncated", K.DONE, K.TERMINATED, K.TRUNCATED} <= set(env.done_keys)
    td = env.rollout(30, break_when_any_done=False)  # several episodes per world (auto-reset)
    nxt = td["next"]
    assert nxt[K.DONE].shape == (3, 30, 2, 1) and nxt["done"].any()
    for name, key in (("done", K.DONE), ("terminated", K.TERMINATED), ("truncated", K.TRUNCATED)):
        assert torch.equal(nxt[key], nxt[name][:, :, None].expand(3, 30, 2, 1))  # the world's flag per robot
    assert torch.equal(nxt["done"], nxt["terminated"] | nxt["truncated"])
    # "state" is the engine's ground truth (the PettingZoo env's state()) of the current event
    last = env.engine.world.ground_truth(None)
    assert last.shape == (3, 6, 15, 15) and torch.equal(nxt[K.STATE][:, -1], torch.from_numpy(last))
    assert td[K.STATE].dtype == torch.float32 and set(td[K.STATE].unique().tolist()) <= {0.0, 1.0}


def test_a_group_level_reset_resets_the_world():
    env = CatmipEnv("task1", num_worlds=2, seed=0)
    env.reset()
    episodes = env.engine.state.episode.copy()
    robots_reset = torch.zeros(2, 2, 1, dtype=torch.bool)
    robots_reset[1, 0] = True  # one robot's flag asks for its world
    env.reset(env.full_done_spec.zero().set((K.ROBOTS, "_reset"), robots_reset))
    assert env.engine.state.episode[0] == episodes[0] and env.engine.state.episode[1] != episodes[1]


def test_float_observation_transform():
    def make():
        return TransformedEnv(CatmipEnv("train", num_worlds=2, seed=0), float_observation_transform())

    check_env_specs(make(), seed=0)  # float specs, and random actions that respect the mask
    env, raw = make(), CatmipEnv("train", num_worlds=2, seed=0)
    spec = env.observation_spec[K.GLOBAL_MAP]
    assert spec.dtype == torch.float32 and spec.space.low.min() == 0 and spec.space.high.max() == 1
    td, ref = env.reset(), raw.reset()
    for _ in range(3):
        for key in (K.GLOBAL_MAP, K.LOCAL_MAP):
            assert td[key].dtype == torch.float32 and torch.equal(td[key], ref[key].float() * OBS_SCALE)
        action = env.rand_action(td)[K.ACTION]  # sampled from the transformed env's masked spec
        td, ref = env.step(td.set(K.ACTION, action)), raw.step(ref.set(K.ACTION, action))
        td, ref = env.step_mdp(td), raw.step_mdp(ref)
    assert set(td[K.GLOBAL_MAP].unique().tolist()) <= {0.0, OBS_SCALE, 1.0}


def test_gae_reads_the_group_done_keys():
    """TorchRL's GAE on the env's own keys, nothing copied: with a zero critic and gamma = lambda = 1
    the advantage is each robot's reward to go up to the end of its episode."""
    env = CatmipEnv("task1", num_worlds=2, seed=0, horizon_ticks=40)
    td = env.rollout(40, break_when_any_done=False)
    zero = TensorDictModule(
        lambda m: torch.zeros(*m.shape[:-3], 1), in_keys=[K.GLOBAL_MAP], out_keys=[K.VALUE]
    )
    gae = GAE(gamma=1.0, lmbda=1.0, value_network=zero)
    gae.set_keys(reward=K.REWARD, done=K.DONE, terminated=K.TERMINATED, value=K.VALUE)
    gae(td)
    reward, done = td["next", K.REWARD], td["next", K.DONE]
    to_go = torch.zeros_like(reward[:, 0])
    expected = torch.zeros_like(reward)
    for t in reversed(range(td.batch_size[1])):
        to_go = reward[:, t] + to_go * ~done[:, t]
        expected[:, t] = to_go
    assert td["advantage"].shape == (2, 40, 2, 1) and done.any()
    torch.testing.assert_close(td["advantage"], expected)


def test_pettingzoo_wrapper_keys_are_double_nested():
    """What docs/torchrl.md says about TorchRL's PettingZooWrapper (CatmipEnv is the recommended way)."""
    from torchrl.envs.libs.pettingzoo import PettingZooWrapper

    from catmip_env import search_rescue_v0

    env = PettingZooWrapper(
        search_rescue_v0.parallel_env(preset="task1"), use_mask=True, categorical_actions=True
    )
    td = env.rollout(3)
    assert env.group_map == {"robot": ["robot_0", "robot_1"]}
    assert td["robot", "observation", "observation", "global_map"].dtype == torch.float32
    assert td["robot", "action_mask"].shape == (3, 2, 49) and ("robot", "info", "active") in td.keys(True)


def test_the_deciding_observation_is_the_active_rows_of_the_event_observation():
    import numpy as np

    from catmip_env import make_config
    from catmip_env.engines.events import EventEngine
    from catmip_rl.adapters.torchrl_env import deciding_observation, engine_observation

    engine = EventEngine(make_config("task3"), num_worlds=3, seed=5)  # six robots: some busy at an event
    engine.reset()
    rng = np.random.default_rng(0)
    partial = 0
    for _ in range(12):
        active = torch.from_numpy(engine.active)
        full = engine_observation(engine).get(K.ROBOTS)[active]
        rows = deciding_observation(engine).get(K.ROBOTS)
        assert rows.batch_size == (int(active.sum()),) and set(rows.keys()) == set(full.keys())
        for key in full.keys():
            assert torch.equal(rows.get(key), full.get(key)), key
        partial += 0 < active.sum() < active.numel()
        masks = engine.masks
        engine.step(np.array([[rng.choice(np.flatnonzero(m)) for m in world] for world in masks]))
    assert partial  # the point of it: events where only some robots decide
