"""Training on a GPU (skipped where torch sees none): the update runs on the device while the worlds
are played on the CPU by a copy of the model refreshed at every collection; checkpoints resume, export
and load on the CPU; the CLI's ``--device cuda``."""

import copy
import csv

import numpy as np
import pytest
import torch

from catmip_rl.cli.main import main as cli
from catmip_rl.store.checkpoint import load_model
from catmip_rl.training.collect import Collector
from catmip_rl.training.presets import make_train_config
from catmip_rl.training.train import build_run, ppo_iteration, train

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")


@pytest.fixture(autouse=True)
def _full_fp32():
    # TF32 convolutions and products round to 10 bits: compare the GPU's arithmetic with the CPU's in fp32
    before = torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32
    torch.backends.cudnn.allow_tf32 = torch.backends.cuda.matmul.allow_tf32 = False
    yield
    torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32 = before


def _params(model):
    return torch.cat([p.detach().flatten().cpu() for p in model.parameters()])


def _close(a, b, moved):
    """``a`` and ``b`` differ by under 1 % of how far the update ``moved`` the weights (Adam's first
    steps follow the gradient's sign, which rounding can flip where a gradient is nearly zero)."""
    return (a - b).norm() <= 0.01 * moved.norm() and moved.norm() > 0


def test_the_gpu_update_matches_the_cpu_one(tmp_path):
    cfg = make_train_config("tiny", iterations=1, eval_every=0, checkpoint_every=0)
    runs = {d: build_run(cfg.replace(device=d)) for d in ("cpu", "cuda")}
    start = _params(runs["cpu"].model)
    assert torch.equal(start, _params(runs["cuda"].model)) and next(runs["cuda"].model.parameters()).is_cuda
    out = {d: ppo_iteration(r, tmp_path) for d, r in runs.items()}
    # the same weights played the same episodes on the CPU ...
    np.testing.assert_array_equal(out["cpu"][2].action, out["cuda"][2].action)
    # ... and the update on the GPU computed what the CPU's did
    for key in ("loss/policy", "loss/value", "ppo/approx_kl", "ppo/grad_norm"):
        assert out["cuda"][0][key] == pytest.approx(out["cpu"][0][key], rel=1e-3, abs=1e-6), key
    cpu, gpu = _params(runs["cpu"].model), _params(runs["cuda"].model)
    assert _close(gpu, cpu, cpu - start)


def test_collection_plays_the_gpu_models_current_weights(tmp_path):
    cfg = make_train_config("tiny", iterations=2, eval_every=0, checkpoint_every=0, device="cuda")
    run = build_run(cfg)
    probe = Collector(cfg.env_config(), 4, seed=11)  # one collector: its CPU copy is refreshed per call
    for _ in range(2):
        ppo_iteration(run, tmp_path)
        on_gpu = probe.collect(run.model, 0, deterministic=True)
        here = Collector(cfg.env_config(), 4, seed=11).collect(
            copy.deepcopy(run.model).cpu(), 0, deterministic=True
        )
        np.testing.assert_array_equal(on_gpu.action, here.action)
        np.testing.assert_allclose(on_gpu.value, here.value, rtol=1e-5, atol=1e-6)


def test_a_collector_copies_a_gpu_model_and_leaves_a_cpu_one_alone():
    cfg = make_train_config("tiny")
    on_cpu = build_run(cfg).model
    before = _params(on_cpu)
    on_gpu = build_run(cfg.replace(seed=1, device="cuda")).model
    col = Collector(cfg.env_config(), 2, seed=0)
    col.collect(on_cpu, 0, deterministic=True)
    col.collect(on_gpu, 0, deterministic=True)  # its CPU copy is new, not the CPU model refreshed
    assert torch.equal(_params(on_cpu), before) and not torch.equal(before, _params(on_gpu))


def test_a_gpu_run_resumes_exports_and_loads_on_the_cpu(tmp_path):
    cfg = make_train_config("tiny", iterations=2, eval_every=1, checkpoint_every=1, device="cuda")
    a = train(cfg, tmp_path / "a", progress=False)
    first = torch.load(
        tmp_path / "a" / "checkpoints" / "iter_000001.pt", map_location="cpu", weights_only=False
    )
    # rewind to iteration 1 and resume on the GPU
    ckpts = tmp_path / "a" / "checkpoints"
    (ckpts / "latest.pt").write_bytes((ckpts / "iter_000001.pt").read_bytes())
    c = train(cfg, tmp_path / "a", resume=True, progress=False)
    assert next(c.parameters()).is_cuda
    w1 = torch.cat([first["model"][k].flatten() for k, _ in a.named_parameters()])
    assert _close(_params(c), _params(a), _params(a) - w1)
    rows = list(csv.DictReader((tmp_path / "a" / "metrics.csv").open()))
    assert [int(r["iteration"]) for r in rows] == [1, 2] and rows[1]["eval/success_rate"] != ""
    # the exported model holds the GPU run's weights and plays on the CPU
    out = tmp_path / "m.pt"
    assert cli(["export", str(tmp_path / "a"), "--out", str(out)]) == 0
    model = load_model(out)
    assert next(model.parameters()).device.type == "cpu" and torch.equal(_params(model), _params(c))
    played = Collector(cfg.env_config(), 4, seed=3).collect(model, 0, deterministic=True)
    np.testing.assert_array_equal(
        played.action, Collector(cfg.env_config(), 4, seed=3).collect(c, 0, deterministic=True).action
    )


def test_the_cli_trains_on_cuda(tmp_path):
    run = tmp_path / "run"
    assert cli(["train", "--preset", "tiny", "--device", "cuda", "--run-dir", str(run), "--no-progress"]) == 0
    saved = torch.load(run / "checkpoints" / "latest.pt", map_location="cpu", weights_only=False)
    assert saved["iteration"] == 2 and '"device": "cuda"' in (run / "config.json").read_text()


def test_a_bf16_autocast_update_runs_on_cuda(tmp_path):
    cfg = make_train_config(
        "tiny", iterations=1, eval_every=0, checkpoint_every=0, device="cuda", precision="bf16"
    )
    run = build_run(cfg)
    start = _params(run.model)
    row, _, _ = ppo_iteration(run, tmp_path)
    assert run.bf16 and row["ppo/bf16"] == 1.0
    assert all(np.isfinite(row[k]) for k in ("loss/policy", "loss/value", "ppo/approx_kl", "ppo/grad_norm"))
    assert not torch.equal(_params(run.model), start)
