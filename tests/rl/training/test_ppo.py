"""PPO loss: equals TorchRL's ClipPPOLoss on the policy term; busy robots are never loss terms."""

import torch
from tensordict import TensorDict
from torchrl.objectives import ClipPPOLoss

from catmip_rl.adapters import keys as K
from catmip_rl.adapters.torchrl_actor import AmatActor, AmatCritic
from catmip_rl.training.gae import SampleBatch, ValueNorm
from catmip_rl.training.ppo import ppo_loss
from tests.rl.amat.test_amat import _obs
from tests.rl.helpers import shaken_model


def _setup(b=6, n=3, seed=0):
    m = shaken_model(seed=seed)
    obs = _obs(b, n, 15, seed=seed)
    mask = torch.ones(b, n, 49, dtype=torch.bool)
    mask[..., :5] = False
    active = torch.ones(b, n, dtype=torch.bool)
    robots = dict(obs, action_mask=mask, active=active)
    td = TensorDict({K.ROBOTS: TensorDict(robots, batch_size=[b, n])}, batch_size=[b])
    td = AmatActor(m)(td)
    with torch.no_grad():  # move the policy so that ratios differ from 1 and some are clipped
        for p in m.parameters():
            p.add_(0.01 * torch.randn_like(p))
    adv = torch.randn(b, n, generator=torch.Generator().manual_seed(seed))
    batch = SampleBatch(
        global_map=obs["global_map"], local_map=obs["local_map"], agent_class=obs["agent_class"],
        action_mask=mask, order=td[K.ORDER], action=td[K.ACTION], log_prob=td[K.LOG_PROB],
        value=td[K.VALUE][..., 0], advantage=adv, target=torch.randn(b, n), trainable=active.clone(),
    )  # fmt: skip
    return m, td, batch


def test_policy_loss_equals_torchrl_clip_ppo_loss():
    m, td, batch = _setup()
    td.set((K.ROBOTS, "advantage"), batch.advantage[..., None])
    td.set((K.ROBOTS, "value_target"), batch.target[..., None])
    loss_mod = ClipPPOLoss(
        AmatActor(m), AmatCritic(m), clip_epsilon=0.05, entropy_bonus=False, normalize_advantage=False
    )
    loss_mod.set_keys(
        action=K.ACTION, sample_log_prob=K.LOG_PROB, advantage=(K.ROBOTS, "advantage"), value=K.VALUE,
        value_target=(K.ROBOTS, "value_target"),
    )  # fmt: skip
    ref = loss_mod(td.clone())
    _, parts = ppo_loss(m, batch, clip=0.05)
    assert torch.allclose(parts["loss/policy"], ref["loss_objective"].detach(), atol=1e-6)
    assert 0 < parts["ppo/clip_fraction"] < 1


def test_busy_robots_are_inputs_never_loss_terms():
    m, _, batch = _setup()
    batch.trainable[:, 1] = False  # robot 1 busy (or unfinished) in every sample
    loss, _ = ppo_loss(m, batch)
    altered = SampleBatch(**batch.__dict__)
    altered.advantage = batch.advantage.clone()
    altered.advantage[:, 1] = 1e3
    altered.log_prob = batch.log_prob.clone()
    altered.log_prob[:, 1] -= 5.0
    altered.target = batch.target.clone()
    altered.target[:, 1] = -1e3
    loss2, _ = ppo_loss(m, altered)
    assert torch.allclose(loss, loss2)
    # robot 1 is never scored, yet the loss's gradient reaches its token: an input of the others' terms
    captured = {}
    orig = m.score

    def hook(tokens, actions, order, agent_class, select, *args, **kwargs):
        tokens.retain_grad()
        captured["tokens"], captured["select"] = tokens, select
        return orig(tokens, actions, order, agent_class, select, *args, **kwargs)

    m.score = hook
    loss, _ = ppo_loss(m, batch)
    loss.backward()
    assert not captured["select"][:, 1].any() and captured["select"][:, 0].any()
    assert captured["tokens"].grad[:, 1].abs().sum() > 0


def test_value_norm_tracks_and_inverts():
    vn = ValueNorm(beta=0.9)
    x = torch.randn(1000, dtype=torch.float64) * 7 + 3
    for _ in range(200):
        vn.update(x)
    y = vn.normalize(x)
    assert abs(float(y.mean())) < 0.05 and abs(float(y.std()) - 1) < 0.05
    assert torch.allclose(vn.denormalize(y), x, atol=1e-6)


def test_the_rescue_term_is_the_cross_entropy_of_the_labelled_trainable_robots():
    m, _, batch = _setup()
    base, parts0 = ppo_loss(m, batch, label_coef=1.0)  # no labels at all: the paper's loss
    assert parts0["loss/rescue"] == 0
    label = torch.full_like(batch.action, -1)
    label[0, 0], label[1, 2], label[2, 1] = 7, 30, 12
    batch.label = label
    batch.trainable[2, 1] = False  # a busy robot's label is never a term
    plain, parts = ppo_loss(m, batch, label_coef=0.0)
    loss, parts = ppo_loss(m, batch, label_coef=0.5)
    obs = {"global_map": batch.global_map, "local_map": batch.local_map, "agent_class": batch.agent_class}
    logits, _ = m.score(m.embed(obs), batch.action, batch.order, batch.agent_class, batch.trainable,
                        batch.action_mask)  # fmt: skip
    logp = torch.log_softmax(logits.float(), -1)
    rows = torch.nonzero(batch.trainable)  # the order score returns the trainable robots in
    want = [(i, int(label[b, n])) for i, (b, n) in enumerate(rows.tolist()) if label[b, n] >= 0]
    assert len(want) == 2
    expected = -sum(logp[i, a] for i, a in want) / batch.trainable.sum()
    assert torch.allclose(parts["loss/rescue"], expected.detach(), atol=1e-5)
    assert torch.allclose(loss, plain + 0.5 * expected, atol=1e-5)
    sub = batch.index(torch.tensor([0, 1]))  # indexing and moving keep the labels
    assert torch.equal(sub.label, label[:2]) and sub.to("cpu").label is not None
