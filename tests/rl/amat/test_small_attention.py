"""The few-token attention used in training (catmip_rl.amat.kernels.small_attention) against torch's SDPA."""

import pytest
import torch
import torch.nn.functional as F

from catmip_rl.amat.config import AmatConfig
from catmip_rl.amat.kernels.small_attention import small_attention
from catmip_rl.amat.model import decision_order
from tests.rl.helpers import shaken_model


def _sdpa(q, k, v, allowed, heads):
    b, tq, d = q.shape

    def split(x):
        return x.view(b, x.shape[1], heads, d // heads).transpose(1, 2)

    y = F.scaled_dot_product_attention(split(q), split(k), split(v), attn_mask=allowed)
    return y.transpose(1, 2).reshape(b, tq, d)


def _mask(kind, b, tq, tk, gen):
    if kind == "causal":
        return torch.ones(tq, tk, dtype=torch.bool).tril()[None, None]
    if kind == "padding":
        keep = torch.rand(b, 1, 1, tk, generator=gen) > 0.4
        keep[..., 0] = True  # every query keeps a key
        return keep
    return None


@pytest.mark.parametrize(
    "b, tq, tk, d, heads, kind",
    [
        (64, 3, 3, 192, 1, None),
        (32, 6, 6, 64, 4, "causal"),
        (32, 12, 12, 48, 2, "padding"),
        (16, 4, 7, 32, 1, "padding"),  # cross attention: other query and key lengths
        (8, 1, 1, 16, 1, None),
    ],
)
def test_values_and_gradients_match_sdpa(b, tq, tk, d, heads, kind):
    gen = torch.Generator().manual_seed(0)
    q = torch.randn(b, tq, d, generator=gen, requires_grad=True)
    k, v = (torch.randn(b, tk, d, generator=gen, requires_grad=True) for _ in range(2))
    allowed = _mask(kind, b, tq, tk, gen)
    y_ref, y = _sdpa(q, k, v, allowed, heads), small_attention(q, k, v, allowed, heads)
    torch.testing.assert_close(y, y_ref, rtol=1e-5, atol=1e-5)
    g = torch.randn(y.shape, generator=gen)
    for a, r in zip(torch.autograd.grad(y, (q, k, v), g), torch.autograd.grad(y_ref, (q, k, v), g)):
        torch.testing.assert_close(a, r, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("kind", [None, "causal", "padding"])
def test_gradcheck_in_float64(kind):
    gen = torch.Generator().manual_seed(1)
    q = torch.randn(3, 4, 8, generator=gen, dtype=torch.float64, requires_grad=True)
    k, v = (torch.randn(3, 4, 8, generator=gen, dtype=torch.float64, requires_grad=True) for _ in range(2))
    allowed = _mask(kind, 3, 4, 4, gen)
    assert torch.autograd.gradcheck(lambda q, k, v: small_attention(q, k, v, allowed, 2), (q, k, v))


def test_a_query_with_no_key_gets_zeros_and_passes_no_gradient():
    q, k, v = (torch.randn(2, 3, 8, requires_grad=True) for _ in range(3))
    allowed = torch.ones(2, 1, 3, 3, dtype=torch.bool)
    allowed[1, 0, 2] = False  # event 1, query 2: every key masked
    y = small_attention(q, k, v, allowed, 1)
    assert torch.equal(y[1, 2], torch.zeros(8))
    gq, _, _ = torch.autograd.grad(y[1, 2].sum() + y[0].sum(), (q, k, v))
    assert torch.equal(gq[1, 2], torch.zeros(8))
    assert gq[0].abs().sum() > 0


def test_bad_inputs_are_refused():
    q = torch.randn(2, 3, 8)
    with pytest.raises(ValueError, match="divisible"):
        small_attention(q, q, q, None, 3)
    with pytest.raises(ValueError, match="do not fit"):
        small_attention(q, torch.randn(2, 3, 4), torch.randn(2, 3, 4), None, 1)
    with pytest.raises(ValueError, match="one dtype"):
        small_attention(q, q.double(), q, None, 1)


def test_amat_trains_with_it_and_acts_with_sdpa_to_the_same_outputs():
    """With autograd recording (training) AMAT's attention runs here; without (acting), in SDPA."""
    model = shaken_model(AmatConfig(embed_dim=64, n_heads=2, n_blocks=2)).train()
    gen = torch.Generator().manual_seed(0)
    b, n, d = 16, 5, 64
    tokens = torch.randn(b, n, d, generator=gen)
    padding = torch.zeros(b, n, dtype=torch.bool)
    padding[:4, 3:] = True
    active = torch.rand(b, n, generator=gen) > 0.5
    order = decision_order(active, padding)
    actions = torch.randint(0, 49, (b, n), generator=gen)
    cls = F.one_hot(torch.randint(0, 2, (b, n), generator=gen), 2).float()
    outs = []
    for grad in (True, False):
        with torch.set_grad_enabled(grad):
            rep, values = model.encode(tokens, padding)
            outs.append((rep, values, model.decode_parallel(rep, actions, order, cls)))
    for trained, acted in zip(*outs):
        torch.testing.assert_close(trained.detach(), acted, rtol=1e-5, atol=1e-5)
