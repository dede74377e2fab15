"""The async-aware collector (``training.collect``): sampling, bookkeeping, determinism, the last decisions
of a rescued world, shards."""

import numpy as np
import pytest
import torch

from catmip_env import make_config
from catmip_rl.amat.config import AmatConfig
from catmip_rl.amat.model import AMAT
from catmip_rl.training.collect import Collector


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
    from catmip_env.engines.episode_stats import EpisodeRecords, training_stats

    cfg = make_config("task1", map_size=10, horizon_ticks=60)
    model = AMAT(AmatConfig(embed_dim=32))
    whole = Collector(cfg, 4, seed=3).collect(model, 0, deterministic=True)
    shards = [Collector(cfg, 2, seed=3).collect(model, first, deterministic=True) for first in (0, 2)]
    records = EpisodeRecords.concat([r.records for r in shards])
    returns = np.concatenate([r.returns for r in shards])
    merged = training_stats(records, returns, cfg)
    assert merged.keys() == whole.stats.keys()
    for key, value in whole.stats.items():
        assert merged[key] == pytest.approx(value, rel=1e-12, nan_ok=True), key
    assert {"mean_rescue_tick", "mean_target_found_tick", "mean_explored_fraction"} <= merged.keys()
