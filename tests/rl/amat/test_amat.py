"""AMAT: parameter count, the two log-prob paths, masking, permutation and padding invariance."""

import pytest
import torch
import torch.nn.functional as F

from catmip_rl.amat.config import AmatConfig
from catmip_rl.amat.model import AMAT, decision_order
from catmip_rl.amat.weights import finer_pool
from tests.rl.helpers import shaken_model


def _obs(b, n, s, c=2, l=7, seed=0):
    g = torch.Generator().manual_seed(seed)
    return {
        "global_map": torch.randint(0, 5, (b, n, 5 + c, s, s), generator=g, dtype=torch.uint8),
        "local_map": torch.randint(0, 5, (b, n, 4 + c, l, l), generator=g, dtype=torch.uint8),
        "agent_class": F.one_hot(torch.randint(0, c, (b, n), generator=g), c).float(),
    }


def _mask_active(b, n, a=49, seed=0):
    g = torch.Generator().manual_seed(seed + 1)
    active = torch.rand(b, n, generator=g) < 0.6
    active[:, 0] = True
    mask = torch.rand(b, n, a, generator=g) < 0.5
    mask[..., a // 2] = True
    mask[~active] = False
    mask[..., a // 2] |= ~active
    return mask, active


def test_parameter_count_matches_the_paper_minus_the_unused_module():
    assert sum(p.numel() for p in AMAT().parameters()) == 1_171_282
    assert sum(p.numel() for p in AMAT(AmatConfig(window=5)).parameters()) == 1_162_042
    assert 1_280_786 - 1_171_282 == 1_271_546 - 1_162_042 == 109_504


@pytest.mark.parametrize("s", [15, 20, 32, 64])
@pytest.mark.parametrize("n", [1, 2, 6, 12])
def test_any_map_size_and_team_size(s, n):
    m = AMAT().eval()
    obs = _obs(2, n, s)
    mask, active = _mask_active(2, n)
    rep, values = m(obs)
    assert rep.shape == (2, n, 192) and values.shape == (2, n, 1)
    a, lp = m.decode_autoregressive(rep, mask, decision_order(active), active, obs["agent_class"])
    assert a.shape == (2, n) and torch.isfinite(lp).all()


def test_teacher_forced_and_autoregressive_log_probs_agree():
    m = shaken_model()
    obs = _obs(8, 5, 20)
    mask, active = _mask_active(8, 5)
    order = decision_order(active)
    rep, _ = m(obs)
    a, lp = m.decode_autoregressive(rep, mask, order, active, obs["agent_class"])
    logits = m.decode_parallel(rep, a, order, obs["agent_class"], mask)
    lp2 = torch.log_softmax(logits, -1).gather(-1, a[..., None])[..., 0]
    assert torch.allclose(lp2[active], lp[active], atol=1e-5)
    assert (lp[~active] == 0).all()
    # the check is not vacuous: a robot's logits depend on the actions of earlier robots
    b = int(torch.nonzero(active.sum(1) >= 2)[0, 0])
    first, second = order[b, 0], order[b, 1]
    a_alt = a.clone()
    a_alt[b, first] = (
        int(torch.nonzero(mask[b, first])[-1])
        if a[b, first] != torch.nonzero(mask[b, first])[-1]
        else int(torch.nonzero(mask[b, first])[0])
    )
    logits_alt = m.decode_parallel(rep, a_alt, order, obs["agent_class"], mask)
    assert not torch.allclose(logits_alt[b, second], logits[b, second])
    assert torch.allclose(logits_alt[b, first], logits[b, first])  # causal: its own logits unchanged


def test_masked_actions_have_zero_probability():
    m = shaken_model()
    obs = _obs(16, 3, 15)
    mask, active = _mask_active(16, 3)
    order = decision_order(active)
    rep, _ = m(obs)
    for seed in range(5):
        a, _ = m.decode_autoregressive(
            rep, mask, order, active, obs["agent_class"], generator=torch.Generator().manual_seed(seed)
        )
        assert mask.gather(-1, a[..., None]).all()
    probs = torch.softmax(m.decode_parallel(rep, a, order, obs["agent_class"], mask), -1)
    assert (probs[~mask] == 0).all()


def test_permuting_busy_robots_leaves_active_robots_unchanged():
    m = shaken_model()
    n = 6
    obs = _obs(1, n, 20)
    active = torch.tensor([[True, False, True, False, False, True]])
    mask, _ = _mask_active(1, n)
    mask[0, :, :] = True
    rep, _ = m(obs)
    a, _ = m.decode_autoregressive(
        rep, mask, decision_order(active), active, obs["agent_class"], deterministic=True
    )
    base = m.decode_parallel(rep, a, decision_order(active), obs["agent_class"], mask)
    perm = torch.tensor([0, 4, 2, 1, 3, 5])  # shuffles busy robots 1, 3, 4 only
    obs_p = {k: v[:, perm] for k, v in obs.items()}
    rep_p, _ = m(obs_p)
    active_p, a_p = active[:, perm], a[:, perm]
    out = m.decode_parallel(rep_p, a_p, decision_order(active_p), obs_p["agent_class"], mask[:, perm])
    for i in (0, 2, 5):
        assert torch.allclose(out[0, i], base[0, i], atol=1e-4)


def test_padding_mask_makes_padded_and_unpadded_batches_agree():
    m = shaken_model()
    obs = _obs(1, 3, 20)
    mask, active = _mask_active(1, 3)
    active[:] = True
    rep, values = m(obs)
    a, lp = m.decode_autoregressive(
        rep, mask, decision_order(active), active, obs["agent_class"], deterministic=True
    )
    garbage = _obs(1, 2, 20, seed=9)
    padded = {k: torch.cat([obs[k], garbage[k]], dim=1) for k in obs}
    pad = torch.tensor([[False, False, False, True, True]])
    act_p = torch.cat([active, torch.zeros(1, 2, dtype=torch.bool)], 1)
    mask_p = torch.cat([mask, torch.ones(1, 2, 49, dtype=torch.bool)], 1)
    rep_p, values_p = m(padded, key_padding_mask=pad)
    assert torch.allclose(values_p[:, :3], values, atol=1e-5)
    a_p, lp_p = m.decode_autoregressive(
        rep_p, mask_p, decision_order(act_p, pad), act_p, padded["agent_class"], deterministic=True
    )
    assert torch.equal(a_p[:, :3], a) and torch.allclose(lp_p[:, :3], lp, atol=1e-5)


def test_deterministic_decoding_is_reproducible_and_sampling_is_seeded():
    m = shaken_model()
    obs = _obs(4, 3, 15)
    mask, active = _mask_active(4, 3)
    rep, _ = m(obs)
    order = decision_order(active)
    a1, l1 = m.decode_autoregressive(rep, mask, order, active, obs["agent_class"], deterministic=True)
    a2, l2 = m.decode_autoregressive(rep, mask, order, active, obs["agent_class"], deterministic=True)
    assert torch.equal(a1, a2) and torch.equal(l1, l2)
    g = lambda: torch.Generator().manual_seed(3)  # noqa: E731
    s1, _ = m.decode_autoregressive(rep, mask, order, active, obs["agent_class"], generator=g())
    s2, _ = m.decode_autoregressive(rep, mask, order, active, obs["agent_class"], generator=g())
    assert torch.equal(s1, s2)


def test_decision_order():
    active = torch.tensor([[False, True, False, True]])
    assert decision_order(active).tolist() == [[1, 3, 0, 2]]
    pad = torch.tensor([[True, False, False, False]])
    assert decision_order(torch.tensor([[False, False, True, False]]), pad).tolist() == [[2, 1, 3, 0]]


def test_config_validation():
    with pytest.raises(ValueError, match="window"):
        AmatConfig(window=4)
    with pytest.raises(ValueError, match="divisible"):
        AmatConfig(embed_dim=192, n_heads=5)
    with pytest.raises(ValueError, match="unknown AmatConfig"):
        AmatConfig.from_dict({"widow": 7})


def test_initialisation():
    m = AMAT()
    for name, p in m.named_parameters():
        if name.endswith("bias"):
            assert (p == 0).all(), name
    w = m.policy_head[3].weight  # a head: gain 0.01
    assert w.abs().max() < 0.05
    w = m.obs_fc1.weight  # followed by GELU: gain sqrt(2), orthogonal rows
    assert torch.allclose(w @ w.t(), 2 * torch.eye(w.shape[0]), atol=1e-4)


@pytest.mark.parametrize("grad", [False, True])  # with grad on CPU, the global CNN runs in sparse_conv
def test_a_finer_pooled_grid_reads_a_map_as_the_coarse_model_where_it_repeats_the_coarse_cells(grad):
    coarse = shaken_model(AmatConfig(embed_dim=32, pool=2))
    # the global CNN copies map channel 0 (a centre tap), so pooled cells follow its maxima
    with torch.no_grad():
        w = torch.zeros_like(coarse.global_conv.weight)
        w[:, 0, 3, 3] = torch.linspace(-1, 1, w.shape[0])
        coarse.global_conv.weight.copy_(w)
    fine = AMAT(AmatConfig(embed_dim=32, pool=4))
    fine.load_state_dict(finer_pool(coarse.state_dict(), 2, 4))
    obs = _obs(2, 3, 8)
    with torch.set_grad_enabled(grad):
        assert not torch.allclose(coarse.embed(obs), fine.embed(obs), atol=1e-3)  # the fine grid sees more
        # channel 0 constant over each coarse 4x4 cell: every fine 2x2 cell repeats its coarse cell
        gen = torch.Generator().manual_seed(3)
        blocks = torch.randint(0, 5, (2, 3, 2, 2), generator=gen, dtype=torch.uint8)
        obs["global_map"][:, :, 0] = blocks.repeat_interleave(4, -2).repeat_interleave(4, -1)
        assert torch.allclose(coarse.embed(obs), fine.embed(obs), atol=1e-5)
    with pytest.raises(ValueError, match="pool 6 is not a multiple of 4"):
        finer_pool(fine.state_dict(), 4, 6)


@pytest.mark.parametrize(
    "config, padded",
    [(None, False), (None, True), (AmatConfig(embed_dim=32, n_blocks=2, n_heads=2), False)],
)
@pytest.mark.parametrize("grad", [False, True])  # with grad on CPU, attention runs in small_attention
def test_score_equals_encode_and_decode_parallel_at_the_selected_robots(config, padded, grad):
    m = shaken_model(config)
    b, n = 6, 4
    obs = _obs(b, n, 15, seed=3)
    mask, active = _mask_active(b, n, seed=3)
    pad = None
    if padded:
        pad = torch.zeros(b, n, dtype=torch.bool)
        pad[::2, -1] = True  # every other world has one robot fewer
        active &= ~pad
    order = decision_order(active, pad)
    actions = (mask * torch.rand(mask.shape, generator=torch.Generator().manual_seed(4))).argmax(-1)
    select = active & (torch.rand(b, n, generator=torch.Generator().manual_seed(5)) < 0.7)
    select[0] = False  # a world with no selected robot
    with torch.set_grad_enabled(grad):
        tokens = m.embed(obs).detach().requires_grad_(grad)
        rep, values = m.encode(tokens, pad)
        logits = m.decode_parallel(rep, actions, order, obs["agent_class"], mask)
        logits_s, values_s = m.score(tokens, actions, order, obs["agent_class"], select, mask, pad)
    k = int(select.sum())
    assert logits_s.shape == (k, 49) and values_s.shape == (k, 1) and 0 < k < b * n
    assert torch.allclose(logits_s, logits[select], atol=1e-5)
    assert torch.allclose(values_s, values[select], atol=1e-5)
    if grad:  # the same gradients, into every token (unselected robots are still inputs)
        w = torch.randn(k, 49, generator=torch.Generator().manual_seed(7))
        g_full = torch.autograd.grad((logits[select] * w).sum() + values[select].sum(), tokens)[0]
        g_sel = torch.autograd.grad((logits_s * w).sum() + values_s.sum(), tokens)[0]
        assert torch.allclose(g_sel, g_full, atol=1e-5) and g_full[~select].abs().sum() > 0


def _score_args():
    """(model, (tokens, actions, order, agent_class), active, mask) of two worlds of three robots."""
    m = shaken_model()
    obs = _obs(2, 3, 15)
    mask, active = _mask_active(2, 3)
    acts = torch.zeros(2, 3, dtype=torch.long)
    return m, (m.embed(obs), acts, decision_order(active), obs["agent_class"]), active, mask


def test_score_with_nothing_selected():
    m, args, _, mask = _score_args()
    logits, values = m.score(*args, torch.zeros(2, 3, dtype=torch.bool), mask)
    assert logits.shape == (0, 49) and values.shape == (0, 1)
    (logits.sum() + values.sum()).backward()


def test_score_refuses_wrong_shapes():
    m, args, active, mask = _score_args()
    with pytest.raises(ValueError, match="must all be \\(B, N\\)"):
        m.score(*args, active[:, :2], mask)
