"""The sparse global conv + pool used in training (amat.sparse_conv) against the dense torch path."""

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from catmip_env.config import make_config
from catmip_env.engines.events import EventEngine, random_valid_actions
from catmip_rl.amat.config import AmatConfig
from catmip_rl.amat.kernels.sparse_conv import global_conv_pool, global_conv_pool_winners
from catmip_rl.amat.model import decision_order
from catmip_rl.training.gae import SampleBatch
from catmip_rl.training.ppo import make_optimizer, ppo_loss, ppo_update
from catmip_rl.training.presets import make_train_config
from tests.rl.helpers import shaken_model


def _events(preset: str, worlds: int = 6, every: int = 7, seed: int = 0, **overrides):
    """Observations (M, N, ...) of every ``every``-th decision event of random-goal episodes: real maps
    from the first event to the end (merged or, under partial comm, diverging beliefs)."""
    eng = EventEngine(make_config(preset, activation=(2, 5), **overrides), worlds, seed)
    eng.reset()
    rng = np.random.default_rng(seed)
    rows, t = [], 0
    while not eng.state.done.all():
        live = np.flatnonzero(~eng.state.done)
        acts = random_valid_actions(eng.masks, rng)
        if t % every == 0:
            seen = (eng.obs_global, eng.obs_local, eng.state.cls, eng.masks, eng.active, acts)
            rows.append(tuple(np.array(x[live]) for x in seen))
        eng.step(acts)
        t += 1
    return [torch.from_numpy(np.concatenate(col)) for col in zip(*rows)]


def _dense(gmap, weight, bias, pool):
    x = gmap.flatten(0, 1).float() * 0.25
    return F.adaptive_max_pool2d(F.conv2d(x, weight, bias, padding=weight.shape[-1] // 2), pool)


def _both(gmap, weight, bias, pool, seed=0):
    """(values, weight grad, bias grad) of the sparse and the dense path for one upstream gradient."""
    out = []
    for fn in (global_conv_pool, _dense):
        weight.grad = bias.grad = None
        y = fn(gmap, weight, bias, pool)
        up = torch.randn(y.shape, generator=torch.Generator().manual_seed(seed))
        (y * up).sum().backward()
        out.append((y.detach(), weight.grad.clone(), bias.grad.clone()))
    return out


def _exact_reference(gmap, weight, bias, where, up):
    """Float64 dense convolution of the maps, each bin's maximum, and the weight / bias gradients of
    ``sum(up * conv[winning cell])`` when every bin passes its gradient to the cell in ``where``."""
    w64 = weight.detach().double().requires_grad_()
    b64 = bias.detach().double().requires_grad_()
    y = F.conv2d(gmap.flatten(0, 1).double() * 0.25, w64, b64, padding=weight.shape[-1] // 2)
    r, o = y.shape[:2]
    best = F.adaptive_max_pool2d(y.detach(), where.shape[-1])
    at_winner = y.flatten(2).gather(2, where.flatten(2)).view_as(where)  # (R, O, g, g)
    (at_winner * up.double()).sum().backward()
    return best, at_winner.detach(), w64.grad, b64.grad


@pytest.mark.parametrize(
    "preset, overrides, pool",
    [
        ("task1", {}, 4),  # S = 15: uneven pooling bins
        ("task2", {}, 4),
        ("task3", {}, 4),
        ("task2", {"comm_sigma": 2.0, "slam_noise": 0.05}, 4),  # diverging beliefs, noisy maps
        ("task3", {"comm_sigma": 2.0, "slam_noise": 0.05}, 4),  # a near-tie that float32 paths break apart
        ("task2", {}, 3),
    ],
)
def test_matches_the_dense_conv_and_its_gradients(preset, overrides, pool):
    """Exact up to float32 rounding, ties included. A bin's maximum can be a near-tie between cells
    with different patches (float64 values 8e-8 apart in task3 + noise): float32 sums in another order
    (ours, or torch's AVX2 vs AVX-512 convolution kernels) may rank them either way, and the gradient
    then flows into another patch. So the reference is float64: every winning cell must be a float64
    maximum of its bin up to float32 rounding, and the gradients must equal the float64 gradients of
    the same winners."""
    gmap = _events(preset, **overrides)[0]
    torch.manual_seed(1)
    conv = torch.nn.Conv2d(gmap.shape[2], 32, 7, padding=3)
    with torch.no_grad():
        conv.bias.normal_(0, 0.2)
    conv.weight.grad = conv.bias.grad = None
    y = global_conv_pool(gmap, conv.weight, conv.bias, pool)
    up = torch.randn(y.shape, generator=torch.Generator().manual_seed(0))
    (y * up).sum().backward()
    pooled, where = global_conv_pool_winners(gmap, conv.weight, conv.bias, pool)
    assert torch.equal(pooled, y.detach())
    best, at_winner, dw_ref, db_ref = _exact_reference(gmap, conv.weight, conv.bias, where, up)
    assert y.shape == best.shape == (gmap.shape[0] * gmap.shape[1], 32, pool, pool)
    rounding = 1e-6 * float(best.abs().max())  # float32 sums of 7 * 7 * C products of terms <= |w|
    assert float((best - at_winner).max()) <= rounding  # every winner is a maximum (ties: any of them)
    assert torch.allclose(y.double(), best, atol=rounding)
    assert float((conv.weight.grad.double() - dw_ref).abs().max()) <= 1e-5 * float(dw_ref.abs().max())
    assert torch.allclose(conv.bias.grad.double(), db_ref, rtol=1e-5, atol=1e-3)
    # and the float32 dense path agrees wherever its pool picks the same winners (all but near-ties)
    _, dense_where = F.adaptive_max_pool2d(
        F.conv2d(gmap.flatten(0, 1).float() * 0.25, conv.weight.detach(), conv.bias.detach(), padding=3),
        pool,
        return_indices=True,
    )
    assert (dense_where != where).float().mean() < 0.05


def test_random_dense_maps_and_float_inputs_of_other_sizes():
    """Not env maps: every channel dense and random (the kernels' dense fallback); 9 channels, k = 5."""
    g = torch.Generator().manual_seed(3)
    gmap = torch.randint(0, 5, (4, 3, 9, 18, 18), generator=g, dtype=torch.uint8)
    conv = torch.nn.Conv2d(9, 16, 5, padding=2)
    (y, dw, db), (y_ref, dw_ref, db_ref) = _both(gmap, conv.weight, conv.bias, 4)
    assert torch.allclose(y, y_ref, atol=1e-5)
    assert (dw - dw_ref).abs().max() <= 1e-4 * dw_ref.abs().max()
    assert torch.allclose(db, db_ref, rtol=1e-5, atol=1e-3)


def test_results_do_not_depend_on_the_thread_count():
    gmap = _events("task2", worlds=4)[0]
    conv = torch.nn.Conv2d(7, 32, 7, padding=3)
    threads = torch.get_num_threads()
    try:
        results = []
        for n in (1, 2, 3):
            torch.set_num_threads(n)
            results.append(_both(gmap, conv.weight, conv.bias, 4)[0])
    finally:
        torch.set_num_threads(threads)
    for other in results[1:]:
        assert all(torch.equal(a, b) for a, b in zip(results[0], other))


def test_bad_inputs_are_refused():
    w, b = torch.zeros(32, 7, 7, 7), torch.zeros(32)
    with pytest.raises(ValueError, match="uint8"):
        global_conv_pool(torch.zeros(2, 3, 7, 15, 15), w, b, 4)
    with pytest.raises(ValueError, match="uint8"):
        global_conv_pool(torch.zeros(6, 7, 15, 15, dtype=torch.uint8), w, b, 4)
    with pytest.raises(ValueError, match=r"\(M, N, 7, S, S\)"):
        global_conv_pool(torch.zeros(2, 3, 6, 15, 15, dtype=torch.uint8), w, b, 4)


def _batch(preset="task2", worlds=4, seed=0):
    gmap, lmap, cls, mask, active, action = _events(preset, worlds=worlds, seed=seed)
    active = active.bool()
    g = torch.Generator().manual_seed(seed)
    m, n = action.shape
    return SampleBatch(
        global_map=gmap, local_map=lmap, agent_class=F.one_hot(cls.long(), 2).float(),
        action_mask=mask.bool(), order=decision_order(active), action=action.long(),
        log_prob=-torch.rand(m, n, generator=g), value=torch.randn(m, n, generator=g),
        advantage=torch.randn(m, n, generator=g), target=torch.randn(m, n, generator=g), trainable=active,
    )  # fmt: skip


def _float_maps(batch: SampleBatch) -> SampleBatch:
    """The same batch with float maps: AMAT.embed takes the dense torch path for them."""
    return SampleBatch(**(batch.__dict__ | {"global_map": batch.global_map.float() * 0.25}))


def test_training_loss_and_every_gradient_match_the_dense_path():
    batch = _batch()
    model = shaken_model(AmatConfig(embed_dim=64)).train()
    grads = []
    for b in (batch, _float_maps(batch)):
        model.zero_grad()
        loss, _ = ppo_loss(model, b)
        loss.backward()
        grads.append((loss.detach(), {k: p.grad.clone() for k, p in model.named_parameters()}))
    (loss, g), (loss_ref, g_ref) = grads
    assert torch.allclose(loss, loss_ref, rtol=1e-5, atol=1e-6)
    floor = 1e-5 * max(float(v.abs().max()) for v in g_ref.values())  # k-projection biases: zero, up to noise
    for k in g:
        assert (g[k] - g_ref[k]).abs().max() <= 1e-3 * float(g_ref[k].abs().max()) + floor, k


def test_micro_batches_give_the_minibatch_gradient():
    """ppo_update with micro-batches of 5 events equals one pass over each minibatch."""
    batch = _batch(worlds=3)
    cfg = make_train_config("paper", amat={"embed_dim": 32}, epochs=2, minibatches=2)
    params = []
    for micro in (0, 5):
        model = shaken_model(cfg.amat_config()).train()
        opt = make_optimizer(model, cfg.optim)
        optim = cfg.replace(micro_batch=micro).optim
        stats = ppo_update(model, opt, batch, optim, cfg.loss, torch.Generator().manual_seed(0))
        params.append((stats, torch.cat([p.detach().flatten() for p in model.parameters()])))
    (stats, p), (stats_micro, p_micro) = params
    assert torch.allclose(p, p_micro, atol=1e-6)
    for k in stats:
        assert stats_micro[k] == pytest.approx(stats[k], rel=1e-4, abs=1e-6), k


def test_a_bf16_autocast_training_step_runs():
    """CPU bf16 autocast (bench_train --bf16): the float32 sparse conv output meets bf16 layers."""
    batch = _batch(worlds=2).index(torch.arange(6))
    model = shaken_model(AmatConfig(embed_dim=32)).train()
    with torch.autocast("cpu", dtype=torch.bfloat16):
        loss, _ = ppo_loss(model, batch)
    loss.backward()
    assert torch.isfinite(loss)
    assert all(torch.isfinite(p.grad).all() for p in model.parameters() if p.grad is not None)
