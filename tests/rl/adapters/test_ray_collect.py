"""``--collector ray``: TorchRL's RayCollector on a local Ray cluster (loopback) gives the local collector's
rollout, trains from the CLI and resumes exactly; config errors and a missing extra are reported clearly.

The tests marked ``ray`` need the distributed extra (``make test-distributed``; skipped without ray).
"""

import csv
import math
import sys

import numpy as np
import pytest
import torch

from catmip_rl.amat.model import AMAT
from catmip_rl.cli.main import main as cli
from catmip_rl.training.collect import Collector
from catmip_rl.training.config import TrainConfig
from catmip_rl.training.presets import make_train_config
from catmip_rl.training.train import train


@pytest.fixture(scope="module")
def ray_cluster():
    ray = pytest.importorskip("ray")
    ray.init(address="local", num_cpus=2, include_dashboard=False, _node_ip_address="127.0.0.1")
    yield ray
    ray.shutdown()


def _params(model):
    return torch.cat([p.detach().flatten() for p in model.parameters()])


@pytest.mark.ray
def test_ray_rollout_equals_local_rollout(ray_cluster):
    from catmip_rl.adapters.ray_collect import RayRolloutCollector

    cfg = make_train_config("tiny", collector="ray", ray_workers=2)
    torch.manual_seed(1)
    model = AMAT(cfg.amat_config())
    gen = torch.Generator().manual_seed(2)
    remote = RayRolloutCollector(cfg.env_config(), cfg.collection, cfg.seed, cfg.loss.gamma, model)
    try:
        local = Collector(cfg.env_config(), cfg.collection.num_worlds, cfg.seed, cfg.loss.gamma)
        for first in (8, 16):  # the second iteration runs on weights pushed after a change
            a = remote.collect(model, first_episode=first, deterministic=True)
            b = local.collect(model, first_episode=first, deterministic=True)
            assert a.steps == b.steps and np.array_equal(a.valid, b.valid)
            v = b.valid
            for key in ("global_map", "local_map", "agent_class", "action_mask", "active", "order",
                        "action", "ma_return", "ma_ticks"):  # fmt: skip
                assert np.array_equal(getattr(a, key)[v], getattr(b, key)[v]), key
            np.testing.assert_allclose(a.log_prob[v], b.log_prob[v], atol=1e-5)
            np.testing.assert_allclose(a.value[v], b.value[v], atol=1e-5)
            assert np.array_equal(a.final_return, b.final_return)
            assert np.array_equal(a.terminated, b.terminated)
            assert a.stats.keys() == b.stats.keys()
            for key, value in b.stats.items():
                assert a.stats[key] == pytest.approx(value, rel=1e-12, nan_ok=True), key
            with torch.no_grad():  # new weights: a stale one on a worker would show
                for p in model.parameters():
                    p.add_(0.2 * torch.randn(p.shape, generator=gen))
        # sampled actions: reproducible from (seed, episode), whatever ran before
        c = remote.collect(model, first_episode=24)
        d = remote.collect(model, first_episode=24)
        v = c.valid
        assert np.array_equal(c.valid, d.valid) and np.array_equal(c.action[v], d.action[v])
        assert np.array_equal(c.log_prob[v], d.log_prob[v])
    finally:
        remote.close()
    assert ray_cluster.is_initialized()  # it did not start this cluster, so it leaves it running


@pytest.mark.ray
def test_a_model_reading_a_planners_proposals_collects_and_trains_on_ray(ray_cluster, tmp_path):
    """The proposal is an observation part each worker's collector makes (catmip_env.planners.proposals):
    a Ray rollout of a model with AmatConfig.hint carries the local collector's proposals, and it trains."""
    from catmip_rl.adapters.ray_collect import RayRolloutCollector
    from catmip_rl.amat.pointer import make_model

    amat = {"goals": "cell", "embed_dim": 32, "hint": "nearest"}
    cfg = make_train_config("tiny", collector="ray", ray_workers=2, amat=amat, iterations=2, eval_every=0)
    torch.manual_seed(1)
    model = make_model(cfg.amat_config())
    remote = RayRolloutCollector(cfg.env_config(), cfg.collection, cfg.seed, cfg.loss.gamma, model)
    try:
        a = remote.collect(model, first_episode=8, deterministic=True)
    finally:
        remote.close()
    local = Collector(cfg.env_config(), cfg.collection.num_worlds, cfg.seed, cfg.loss.gamma, goal_mode="cell")
    b = local.collect(model, first_episode=8, deterministic=True)
    v = b.valid
    assert np.array_equal(a.valid, v) and np.array_equal(a.hint[v], b.hint[v])
    assert (a.hint[a.active & v[..., None]] >= 0).all()
    trained = train(cfg, tmp_path / "run", progress=False)
    assert trained.config.hint == "nearest" and trained.hint_bias.detach().abs().item() > 0


@pytest.mark.ray
def test_the_shipped_amat_general_trains_on_ray(ray_cluster, tmp_path):
    """amat:general's own recipe (general-coord: cell goals, teammate memory, rrt-relay-coord's
    proposals) continues from the shipped weights on Ray workers, one small PPO iteration on Task 2."""
    cfg = make_train_config(
        "general-coord",
        collector="ray",
        ray_workers=2,
        num_worlds=2,
        iterations=1,
        eval_every=0,
        warm_start="",
        anchor="",
        anchor_coef=0.0,
        worlds=[],
        env_preset="task2",
        env_overrides={"comm_sigma": 2.0},
        init_from="general",
        minibatches=1,
        epochs=1,
    )
    model = train(cfg, tmp_path / "run", progress=False)
    assert model.config.hint == "rrt-relay-coord" and model.config.teammate_memory
    rows = list(csv.DictReader((tmp_path / "run" / "metrics.csv").open()))
    assert len(rows) == 1 and float(rows[0]["samples"]) > 0


@pytest.mark.ray
def test_cli_ray_training_and_exact_resume(ray_cluster, tmp_path):
    run = tmp_path / "run"
    args = ["train", "--preset", "tiny", "--collector", "ray", "--ray-workers", "2", "--no-progress"]
    assert cli([*args, "--run-dir", str(run)]) == 0
    cfg = TrainConfig.from_json((run / "config.json").read_text())
    assert cfg == make_train_config("tiny", collector="ray", ray_workers=2)
    rows = list(csv.DictReader((run / "metrics.csv").open()))
    assert [int(r["iteration"]) for r in rows] == [1, 2]
    assert all(
        float(r["samples"]) > 0 and not math.isnan(float(r["rollout/mean_explored_fraction"])) for r in rows
    )
    assert rows[1]["eval/success_rate"] != ""
    ckpts = run / "checkpoints"
    assert (ckpts / "latest.pt").exists() and (ckpts / "iter_000001.pt").exists()
    saved = torch.load(ckpts / "latest.pt", weights_only=False)
    assert saved["iteration"] == 2 and saved["episodes"] == 16
    # rewind to iteration 1 and resume: the same parameters as the straight run
    (ckpts / "latest.pt").write_bytes((ckpts / "iter_000001.pt").read_bytes())
    resumed = train(cfg, run, resume=True, progress=False)
    straight = AMAT(cfg.amat_config())
    straight.load_state_dict(saved["model"])
    assert torch.equal(_params(resumed), _params(straight))
    assert ray_cluster.is_initialized()


def test_ray_config_errors_and_missing_extra(tmp_path, monkeypatch):
    with pytest.raises(ValueError, match="divisible by ray_workers"):
        make_train_config("tiny", collector="ray", ray_workers=3)
    with pytest.raises(ValueError, match="collector must be"):
        make_train_config("tiny", collector="dask")
    with pytest.raises(ValueError, match="ray_workers must be"):
        make_train_config("tiny", ray_workers=0)
    with pytest.raises(ValueError, match="ray_address"):
        make_train_config("tiny", ray_address="")
    assert cli(["train", "--preset", "tiny", "--run-dir", str(tmp_path / "x"), "--ray-workers", "3",
                "--collector", "ray"]) == 2  # fmt: skip
    monkeypatch.setitem(sys.modules, "ray", None)  # as if the extra were not installed
    cfg = make_train_config("tiny", collector="ray", iterations=1)
    with pytest.raises(ImportError, match=r"pip install 'catmip\[distributed\]'"):
        train(cfg, tmp_path / "r", progress=False)
    assert cli(["train", "--preset", "tiny", "--collector", "ray", "--run-dir", str(tmp_path / "c")]) == 2
    assert not (tmp_path / "r").exists() and not (tmp_path / "c").exists()
