"""Data-parallel PPO gradients (catmip_rl.training.parallel_update): the same update as one process."""

import csv

import pytest
import torch

from catmip_rl.training.parallel_update import ParallelGradients
from catmip_rl.training.ppo import accumulate_gradients, loss_kwargs, make_optimizer, ppo_update
from catmip_rl.training.presets import make_train_config
from catmip_rl.training.train import train
from tests.rl.amat.test_sparse_conv import _batch
from tests.rl.helpers import shaken_model


def _updated(cfg, batch, processes):
    """Parameters and stats after ``ppo_update`` with ``processes`` gradient processes."""
    model = shaken_model(cfg.amat_config()).train()
    opt = make_optimizer(model, cfg.optim)
    gen = torch.Generator().manual_seed(0)
    if processes == 1:
        stats = ppo_update(model, opt, batch, cfg.optim, cfg.loss, gen)
    else:
        with ParallelGradients(model, processes, **loss_kwargs(cfg.loss)) as parallel:
            stats = ppo_update(model, opt, batch, cfg.optim, cfg.loss, gen, parallel)
    return stats, torch.cat([p.detach().flatten() for p in model.parameters()])


@pytest.mark.parametrize("processes", [2, 3])
def test_the_parallel_update_equals_the_one_process_update(processes):
    """Two epochs of two minibatches, micro-batches of 4 events: 3-4 per minibatch, split over the
    processes (one of three gets a single micro-batch, or none on the last minibatch)."""
    batch = _batch(worlds=3)
    cfg = make_train_config("paper", amat={"embed_dim": 32}, epochs=2, minibatches=2, micro_batch=4)
    stats, p = _updated(cfg.replace(update_processes=1), batch, 1)
    stats_par, p_par = _updated(cfg, batch, processes)
    start = torch.cat([q.detach().flatten() for q in shaken_model(cfg.amat_config()).parameters()])
    assert len(batch) > 8 and not torch.allclose(p, start)  # the update moved the parameters
    assert torch.allclose(p, p_par, atol=1e-6)
    for k in stats:
        assert stats_par[k] == pytest.approx(stats[k], rel=1e-4, abs=1e-6), k


def test_errors_are_reported():
    cfg = make_train_config("tiny")
    model = shaken_model(cfg.amat_config())
    with pytest.raises(ValueError, match="processes >= 2"):
        ParallelGradients(model, 1)
    with pytest.raises(ValueError, match="update_processes = 2 computes gradients in CPU processes"):
        make_train_config("paper", device="cuda")
    with pytest.raises(ValueError, match="update_processes must be an int >= 1"):
        make_train_config("tiny", update_processes=0)
    batch = _batch(worlds=2)
    with ParallelGradients(model, 2, **loss_kwargs(cfg.loss)) as parallel:
        with pytest.raises(RuntimeError, match="before set_batch"):
            parallel.backward(model, [torch.arange(2)], 1.0)
        parallel.set_batch(batch)
        bad = [torch.arange(2), torch.tensor([len(batch) + 5])]  # the helper's micro-batch is out of range
        with pytest.raises(RuntimeError, match="gradient helper process 1 failed"):
            parallel.backward(model, bad, 1.0)
        bad_here = [torch.tensor([len(batch) + 5]), torch.arange(2)]  # this process's micro-batch
        with pytest.raises(IndexError):
            parallel.backward(model, bad_here, 1.0)
        # the helper survives its error, and the failed calls left no answer in the pipe
        parts = [torch.arange(2), torch.arange(2, 4)]
        model.zero_grad(set_to_none=True)
        parallel.backward(model, parts, 2.0)
        got = [p.grad.clone() for p in model.parameters()]
    model.zero_grad(set_to_none=True)
    accumulate_gradients(model, batch, parts, 2.0, **loss_kwargs(cfg.loss))
    for g, p in zip(got, model.parameters()):
        assert torch.allclose(g, p.grad, atol=1e-6)


def test_training_with_two_update_processes(tmp_path):
    cfg = make_train_config("tiny", iterations=2, eval_every=0, update_processes=2)
    model = train(cfg, tmp_path / "run", progress=False)
    rows = list(csv.DictReader((tmp_path / "run" / "metrics.csv").open()))
    assert [int(r["iteration"]) for r in rows] == [1, 2] and all(float(r["ppo/grad_norm"]) > 0 for r in rows)
    one = train(cfg.replace(update_processes=1), tmp_path / "one", progress=False)
    for a, b in zip(model.parameters(), one.parameters()):
        assert torch.allclose(a, b, atol=1e-5)
