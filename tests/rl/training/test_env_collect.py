"""The TorchRL env over the event engine, and the async-aware collector."""

import numpy as np
import pytest
import torch
from tensordict.nn import TensorDictModule
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import check_env_specs
from torchrl.objectives.value import GAE

from catmip_env import make_config
from catmip_env.constants import OBS_SCALE
from catmip_rl.adapters import keys as K
from catmip_rl.adapters.torchrl_actor import AmatActor
from catmip_rl.adapters.torchrl_env import CatmipEnv, float_observation_transform
from catmip_rl.amat.config import AmatConfig
from catmip_rl.amat.model import AMAT
from catmip_rl.training.collect import Collector


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


def test_collector_samples_and_bookkeeping():
    cfg = make_config("train", horizon_ticks=80)
    col = Collector(cfg, 6, seed=3)
    model = AMAT(AmatConfig(embed_dim=32))
    r = col.collect(model, first_episode=0, generator=torch.Generator().manual_seed(0))
    eng = col.engine
    assert eng.state.done.all() and r.valid.shape == (r.steps, 6)
    assert r.valid[0].all() and r.valid[-1].any()  # the last row holds the longest episode
    act = r.active & r.valid[..., None]
    assert act[0].all()  # the joint first decision
    chosen = np.take_along_axis(r.action_mask, r.action[..., None], -1)[..., 0]
    assert chosen[act].all()  # every stored goal was allowed
    assert (r.log_prob[~act] == 0).all() and (r.log_prob[act] <= 0).all()
    # each row's order lists the active robots first
    for t, b in zip(*np.nonzero(r.valid)):
        k = int(r.active[t, b].sum())
        assert r.active[t, b, r.order[t, b, :k]].all()
    # with gamma = 1 the macro-action returns add up to each robot's episode return
    ret = (r.ma_return * act).sum(0) + r.final_return  # (B, N)
    for k, cls in enumerate(cfg.classes):
        sel = eng.state.cls == k
        if sel.any():
            assert np.isclose(ret[sel].mean(), r.stats[f"return_{cls.name}"])
    assert 0 <= r.stats["success_rate"] <= 1 and r.stats["mean_episode_ticks"] > 0


def test_collection_is_deterministic():
    cfg = make_config("train", horizon_ticks=60)
    model = AMAT(AmatConfig(embed_dim=32))
    a = Collector(cfg, 4, seed=5).collect(model, 8, torch.Generator().manual_seed(1))
    b = Collector(cfg, 4, seed=5).collect(model, 8, torch.Generator().manual_seed(1))
    for name in ("action", "log_prob", "active", "ma_return", "valid", "global_map"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


def test_a_rescued_worlds_last_decisions_are_trained_with_advantage_r_minus_v():
    """A rescue completes every robot's macro-action (docs/design.md#asynchronous-gae): the rescuer's
    decision that reached the target is in the batch with advantage R - V (normalised with the rest), a
    truncated world's last decisions are not."""
    from catmip_rl.training.gae import ValueNorm, async_gae, build_batch

    cfg = make_config("task1", map_size=10, horizon_ticks=100)
    col = Collector(cfg, 8, seed=0)
    r = col.collect(AMAT(AmatConfig(embed_dim=32)), 0, torch.Generator().manual_seed(0))
    st = col.engine.state
    assert np.array_equal(r.terminated, st.rescue_tick >= 0)
    assert r.terminated.any() and not r.terminated.all()  # both kinds of endings in this batch
    norm = ValueNorm()
    values = norm.denormalize(torch.from_numpy(r.value).double()).numpy()
    raw, _, trainable = async_gae(
        r.active, r.valid, values, r.ma_return, r.ma_ticks, r.final_return, r.terminated, 1.0, 0.95
    )
    batch, _ = build_batch(r, norm, 1.0, 0.95, cfg.num_classes, torch.device("cpu"))
    event_row = np.cumsum(r.valid.reshape(-1)).reshape(r.valid.shape) - 1  # (T, B) -> batch row
    mean, std = raw[trainable].mean(), raw[trainable].std(ddof=1)
    for b in range(8):
        for i in range(cfg.num_robots):
            last = int(np.flatnonzero(r.valid[:, b] & r.active[:, b, i])[-1])
            row = int(event_row[last, b])
            assert bool(batch.trainable[row, i]) == bool(r.terminated[b])
            assert raw[last, b, i] == pytest.approx(r.final_return[b, i] - values[last, b, i])
            if r.terminated[b]:
                assert float(batch.advantage[row, i]) == pytest.approx(
                    (raw[last, b, i] - mean) / std, rel=1e-4
                )
                if st.cls[b, i] == 0:  # the rescuer's last macro-action holds the success reward
                    assert r.final_return[b, i] > 100


def test_shards_merged_as_records_give_the_whole_batchs_statistics():
    """What the Ray collector does with its workers' shards: concatenate their episode records and
    compute the statistics once; they equal those of one collector over all the worlds."""
    from catmip_env.play import EpisodeRecords
    from catmip_rl.training.collect import episode_stats

    cfg = make_config("task1", map_size=10, horizon_ticks=60)
    model = AMAT(AmatConfig(embed_dim=32))
    whole = Collector(cfg, 4, seed=3).collect(model, 0, deterministic=True)
    shards = [Collector(cfg, 2, seed=3).collect(model, first, deterministic=True) for first in (0, 2)]
    records = EpisodeRecords.concat([r.records for r in shards])
    returns = np.concatenate([r.returns for r in shards])
    merged = episode_stats(records, returns, cfg)
    assert merged.keys() == whole.stats.keys()
    for key, value in whole.stats.items():
        assert merged[key] == pytest.approx(value, rel=1e-12, nan_ok=True), key
    assert {"mean_rescue_tick", "mean_target_found_tick", "mean_explored_fraction"} <= merged.keys()
