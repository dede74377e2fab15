"""FastAmat (numba batch-1 decisions) against the torch AMAT: convolution, tokens, decisions, sampling."""

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from catmip_env.config import make_config
from catmip_env.engines.events import EventEngine
from catmip_rl.amat.config import AmatConfig
from catmip_rl.amat.kernels.conv import RUN_MAX, conv_weights, ones_conv
from catmip_rl.amat.model import decision_order
from catmip_rl.amat.onboard.fast_amat import FastAmat
from tests.rl.helpers import shaken_model

SMALL = AmatConfig(embed_dim=32, n_blocks=2, n_heads=2)
ODD = AmatConfig(window=5, local_size=5, pool=3, n_classes=3, embed_dim=48, n_heads=3)  # uneven pool bins
TOL = 1e-4


@pytest.fixture(scope="module")
def models():
    out = {}
    for name, cfg in (("table2", None), ("small", SMALL), ("odd", ODD)):
        m = shaken_model(cfg)
        out[name] = (m, FastAmat.from_model(m))
    return out


def _belief(rng, s):
    """Explored rectangles (long runs, often a majority), walls and obstacles, a target stamp with clues."""
    b = np.zeros((3, s, s), np.uint8)
    for _ in range(3):
        (r0, r1), (c0, c1) = np.sort(rng.integers(0, s + 1, (2, 2)), axis=1)
        b[0, r0:r1, c0:c1] = 4
    b[1, rng.integers(s)], b[1, :, rng.integers(s)] = 4, 4
    b[1][rng.random((s, s)) < 0.05] = 4
    r, c = rng.integers(1, s - 1, 2)
    b[2, r - 1 : r + 2, c - 1 : c + 2] = 1
    b[2, r, c] = 4
    return b


def _random_obs(rng, n, s, c=2, l=7):
    """Team observation of one world (uint8). Belief channels: robot 0's; the same with a few cells
    changed (sparse difference); or random (dense). Per-robot channels: 3x3 stamps and a goal cell."""
    g = np.zeros((n, 5 + c, s, s), np.uint8)
    local = np.zeros((n, 4 + c, l, l), np.uint8)
    shared = _belief(rng, s)
    for i in range(n):
        g[i, :3] = shared
        if i % 4 == 1:
            cells = rng.integers(0, s, (2, 6))
            g[i, rng.integers(0, 3, 6), cells[0], cells[1]] = rng.integers(0, 5, 6)
        elif i % 4 == 3:
            g[i, :3] = rng.integers(0, 5, (3, s, s))
        r, col = rng.integers(0, s, 2)
        g[i, 3, r, col] = 4
        for ch in range(4, 5 + c):
            for _ in range(rng.integers(0, 3)):
                r, col = rng.integers(0, s, 2)
                g[i, ch, max(r - 1, 0) : r + 2, max(col - 1, 0) : col + 2] = 4
        if i % 3 == 2:
            local[i] = rng.integers(0, 5, (4 + c, l, l))
        else:
            local[i, 0] = np.where(rng.random((l, l)) < 0.8, 4, 0)
            local[i, 1:][rng.random((3 + c, l, l)) < 0.1] = 4
    return g, local, rng.integers(0, c, n)


def _mask_active(rng, n, a, kind):
    active = np.ones(n, bool) if kind == "all" else rng.random(n) < 0.5
    if kind == "some":
        active[rng.integers(n)] = True
    mask = rng.random((n, a)) < 0.4
    mask[:, a // 2] = True
    mask[~active] = False
    mask[~active, rng.integers(a)] = True  # busy robots: exactly one allowed action
    return mask, active


def _torch_obs(g, local, cls, c=2):
    """Batch-1 torch observation; ``cls`` (N,) indices or (N, C) class vectors."""
    cls = torch.from_numpy(np.asarray(cls))
    return {
        "global_map": torch.from_numpy(g)[None],
        "local_map": torch.from_numpy(local)[None],
        "agent_class": (F.one_hot(cls, c) if cls.ndim == 1 else cls).float()[None],
    }


def _model_obs(rng, m, n, s):
    """Random observation shaped for model m."""
    return _random_obs(rng, n, s, m.config.n_classes, m.config.local_size)


def _torch_decide(m, g, local, cls, mask, active):
    """The torch path: (tokens, rep, actions, log-probs, values) of one world."""
    obs = _torch_obs(g, local, cls, m.config.n_classes)
    act, msk = torch.from_numpy(active)[None], torch.from_numpy(mask)[None]
    with torch.no_grad():
        tokens = m.embed(obs)
        rep, values = m.encode(tokens)
        a, lp = m.decode_autoregressive(
            rep, msk, decision_order(act), act, obs["agent_class"], deterministic=True
        )
    return tokens[0].numpy(), rep[0].numpy(), a[0].numpy(), lp[0].numpy(), values[0, :, 0].numpy()


def _assert_same_decision(m, fast, g, local, cls, mask, active):
    _, _, a_t, lp_t, v_t = _torch_decide(m, g, local, cls, mask, active)
    a, lp, v = fast.decide(g, local, cls, mask, active)
    assert a.dtype == np.int64 and lp.dtype == np.float32 and v.dtype == np.float32
    np.testing.assert_array_equal(a, a_t)
    np.testing.assert_allclose(lp, lp_t, atol=TOL, rtol=0)
    np.testing.assert_allclose(v, v_t, atol=TOL, rtol=0)
    assert mask[np.arange(len(a)), a].all()
    assert (lp[~active] == 0).all()


@pytest.mark.parametrize("s", [15, 20, 32])
def test_shared_sparse_global_conv_equals_conv2d(models, s):
    m, fast = models["table2"]
    rng = np.random.default_rng(s)
    maps = [_random_obs(rng, n, s)[0] for n in (1, 3, 6)]
    mostly_explored = maps[-1].copy()
    mostly_explored[:, 0] = 4  # a nonzero majority value ...
    mostly_explored[:, 0, 2:5, 3 : s - 2] = 0  # ... and the runs of cells that differ from it
    maps.append(mostly_explored)
    maps.append(rng.normal(size=(2, 7, s, s)).astype(np.float32))  # float, no zeros: dense everywhere
    runs = np.zeros((2, 7, s, s), np.uint8)  # row r: runs of 1 .. s cells (RUN_MAX and longer, in pieces)
    for r in range(s):
        n = r + 1
        runs[:, 3 + r % 4, r, s - n :] = 1 + r % 4
        runs[1, 3 + r % 4, r, : max(0, s - n - 1)] = 2  # and a second run before it, in robot 1's map
    assert s > RUN_MAX
    maps.append(runs)
    for g in maps:
        x = torch.from_numpy(g).float() * (0.25 if g.dtype == np.uint8 else 1.0)
        with torch.no_grad():
            ref = F.conv2d(x, m.global_conv.weight, m.global_conv.bias, padding=3).numpy()
        np.testing.assert_allclose(fast.global_conv(g), ref, atol=1e-5 * np.abs(ref).max(), rtol=0)


@pytest.mark.parametrize("k, h, w", [(7, 20, 20), (7, 5, 9), (3, 7, 7), (5, 4, 11)])
def test_ones_conv_equals_conv2d(k, h, w):
    """``ones_conv``: the convolution of an all-ones plane per input channel, for kernels larger than
    the plane too."""
    rng = np.random.default_rng(k * h * w)
    weight = torch.from_numpy(rng.normal(size=(6, 3, k, k)).astype(np.float32))
    with torch.no_grad():
        ref = F.conv2d(torch.ones(1, 3, h, w), weight, padding=k // 2)[0]  # (O, H, W)
        per_channel = [
            F.conv2d(torch.ones(1, 1, h, w), weight[:, c : c + 1], padding=k // 2)[0] for c in range(3)
        ]
    flipped = conv_weights(weight.numpy(), np.zeros(6, np.float32)).g_w
    ones = ones_conv(flipped, h, w)  # (C, H, W, O)
    assert ones.shape == (3, h, w, 6) and ones.dtype == np.float32
    for c in range(3):
        np.testing.assert_allclose(ones[c].transpose(2, 0, 1), per_channel[c].numpy(), atol=1e-5)
    np.testing.assert_allclose(ones.sum(0).transpose(2, 0, 1), ref.numpy(), atol=1e-5)


@pytest.mark.parametrize("name", ["table2", "small", "odd"])
def test_tokens_rep_and_values_match_torch(models, name):
    m, fast = models[name]
    rng = np.random.default_rng(1)
    g, local, cls = _model_obs(rng, m, 5, 20)
    mask, active = _mask_active(rng, 5, m.config.num_actions, "all")
    tokens, rep, _, _, values = _torch_decide(m, g, local, cls, mask, active)
    np.testing.assert_allclose(fast.embed(g, local, cls), tokens, atol=TOL, rtol=0)
    rep_f, values_f = fast.encode(tokens)
    np.testing.assert_allclose(rep_f, rep, atol=TOL, rtol=0)
    np.testing.assert_allclose(values_f, values, atol=TOL, rtol=0)


@pytest.mark.parametrize("name", ["table2", "small", "odd"])
@pytest.mark.parametrize("n,s", [(1, 15), (2, 15), (3, 20), (6, 32), (12, 20)])
def test_decisions_match_torch_on_random_observations(models, name, n, s):
    m, fast = models[name]
    rng = np.random.default_rng(n * 100 + s)
    for kind in ("all", "some"):
        g, local, cls = _model_obs(rng, m, n, s)
        mask, active = _mask_active(rng, n, m.config.num_actions, kind)
        _assert_same_decision(m, fast, g, local, cls, mask, active)


@pytest.mark.parametrize("preset", ["task1", "task2", "task3"])
@pytest.mark.parametrize("comm_sigma", [None, 2.0])
def test_decisions_match_torch_on_env_observations(models, preset, comm_sigma):
    """Real macro-observations along an episode; under partial communication beliefs differ."""
    m, fast = models["table2"]
    eng = EventEngine(make_config(preset, comm_sigma=comm_sigma), num_worlds=1, seed=3)
    ev = eng.reset()
    rng = np.random.default_rng(0)
    beliefs_differ = False
    for _ in range(12):
        g, local = eng.obs_global[0].copy(), eng.obs_local[0].copy()
        mask, active, cls = eng.masks[0].astype(bool), ev.active[0].copy(), eng.state.cls[0].copy()
        beliefs_differ |= any(not np.array_equal(g[0, :3], g[i, :3]) for i in range(1, len(g)))
        _assert_same_decision(m, fast, g, local, cls, mask, active)
        partly = active & (rng.random(len(active)) < 0.5)
        _assert_same_decision(m, fast, g, local, cls, mask, partly)
        a, _, _ = fast.decide(g, local, cls, mask, active, deterministic=False, rng=rng)
        ev = eng.step(a[None])
        if ev.terminated[0] or ev.truncated[0]:
            break
    if comm_sigma is not None:
        assert beliefs_differ  # the shared-channel grouping really met different beliefs


@pytest.mark.parametrize("name", ["table2", "small"])
def test_sampling_picks_allowed_actions_with_teacher_forced_log_probs(models, name):
    m, fast = models[name]
    rng = np.random.default_rng(7)
    n = 6
    g, local, cls = _random_obs(rng, n, 15)
    mask, active = _mask_active(rng, n, m.config.num_actions, "some")
    obs = _torch_obs(g, local, cls)
    with torch.no_grad():
        rep, _ = m.encode(m.embed(obs))
    order = decision_order(torch.from_numpy(active)[None])
    seen = set()
    for seed in range(10):
        a, lp, _ = fast.decide(
            g, local, cls, mask, active, deterministic=False, rng=np.random.default_rng(seed)
        )
        assert mask[np.arange(n), a].all()
        with torch.no_grad():
            logits = m.decode_parallel(
                rep, torch.from_numpy(a)[None], order, obs["agent_class"], torch.from_numpy(mask)[None]
            )
        lp_t = torch.log_softmax(logits, -1)[0].gather(-1, torch.from_numpy(a)[:, None])[:, 0].numpy()
        np.testing.assert_allclose(lp[active], lp_t[active], atol=TOL, rtol=0)
        assert (lp[~active] == 0).all()
        seen.add(tuple(a))
        again = fast.decide(g, local, cls, mask, active, deterministic=False, rng=np.random.default_rng(seed))
        np.testing.assert_array_equal(again[0], a)
    assert len(seen) > 1


def test_input_forms_agree(models):
    m, fast = models["small"]
    rng = np.random.default_rng(5)
    g, local, cls = _random_obs(rng, 4, 15)
    mask, active = _mask_active(rng, 4, m.config.num_actions, "all")
    base = fast.decide(g, local, cls, mask, active)
    as_float = fast.decide(g * np.float32(0.25), local * np.float32(0.25), np.eye(2)[cls], mask, active)
    for x, y in zip(base, as_float):
        np.testing.assert_allclose(x, y, atol=1e-6)
    # a class vector that is not one-hot takes the computed (not tabulated) class encodings
    soft = np.full((4, 2), 0.5, np.float32)
    _, _, a_t, lp_t, v_t = _torch_decide(m, g, local, soft, mask, active)
    a, lp, v = fast.decide(g, local, soft, mask, active)
    np.testing.assert_array_equal(a, a_t)
    np.testing.assert_allclose(lp, lp_t, atol=TOL, rtol=0)
    np.testing.assert_allclose(v, v_t, atol=TOL, rtol=0)


def test_bad_inputs_raise(models):
    _, fast = models["small"]
    rng = np.random.default_rng(0)
    g, local, cls = _random_obs(rng, 3, 15)
    mask, active = _mask_active(rng, 3, 49, "all")
    with pytest.raises(ValueError, match="global_map"):
        fast.decide(g[:, :6], local, cls, mask, active)
    with pytest.raises(ValueError, match="local_map"):
        fast.decide(g, local[:2], cls, mask, active)
    with pytest.raises(ValueError, match="action_mask"):
        fast.decide(g, local, cls, mask[:, :10], active)
    with pytest.raises(ValueError, match="rng"):
        fast.decide(g, local, cls, mask, active, deterministic=False)
