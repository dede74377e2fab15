"""PPO step control (target-KL stop, LR schedule over iterations or a time budget), the value-only
warm-up, and the per-epoch log."""

import pytest
import torch

from catmip_rl.amat.config import AmatConfig
from catmip_rl.training.ppo import lr_factor, make_optimizer, ppo_update
from catmip_rl.training.presets import make_train_config
from tests.rl.amat.test_sparse_conv import _batch
from tests.rl.helpers import shaken_model


def _params(model, value_head: bool):
    return torch.cat([p.detach().flatten().clone() for n, p in model.named_parameters()
                      if n.startswith("value_head.") == value_head])  # fmt: skip


def _on_policy(batch, model):
    """The batch with the model's own log-probs of the stored actions: KL 0 before the first step."""
    obs = {"global_map": batch.global_map, "local_map": batch.local_map, "agent_class": batch.agent_class}
    sel = batch.trainable
    with torch.no_grad():
        logits, _ = model.score(model.embed(obs), batch.action, batch.order, batch.agent_class, sel,
                                batch.action_mask)  # fmt: skip
        logp = torch.log_softmax(logits, -1).gather(-1, batch.action[sel][:, None])[:, 0]
    log_prob = batch.log_prob.clone()
    log_prob[sel] = logp
    return type(batch)(**(batch.__dict__ | {"log_prob": log_prob}))


def _update(cfg, **kwargs):
    model = shaken_model(cfg.amat_config()).train()
    batch = _on_policy(_batch(worlds=3), model)
    opt = make_optimizer(model, cfg.optim)
    before = (_params(model, False), _params(model, True))
    log: list[dict] = []
    gen = torch.Generator().manual_seed(0)
    stats = ppo_update(model, opt, batch, cfg.optim, cfg.loss, gen, epoch_log=log, **kwargs)
    return stats, log, before, (_params(model, False), _params(model, True))


def test_without_a_target_every_epoch_runs_and_is_logged():
    cfg = make_train_config("paper", amat={"embed_dim": 32}, epochs=3, minibatches=2, lr=1e-3)
    stats, log, _, _ = _update(cfg)
    assert stats["ppo/epochs"] == 3 and stats["ppo/early_stop"] == 0
    assert [e["epoch"] for e in log] == [1, 2, 3]
    assert log[0]["ppo/approx_kl"] < log[-1]["ppo/approx_kl"]  # the policy moves away from the old one
    assert stats["ppo/approx_kl"] > 0
    assert all({"loss/policy", "ppo/clip_fraction"} <= set(e) for e in log)


def test_a_target_kl_stops_the_epochs_before_the_step_that_would_exceed_it():
    cfg = make_train_config("paper", amat={"embed_dim": 32}, epochs=5, minibatches=2, lr=1e-3)
    full, full_log, _, _ = _update(cfg)
    # the first minibatch is the collecting policy itself (KL 0): it always steps
    target = full_log[1]["ppo/approx_kl"] / 2
    stats, log, _, _ = _update(cfg.replace(target_kl=target))
    assert stats["ppo/early_stop"] == 1 and stats["ppo/approx_kl"] > target
    assert 0 < stats["ppo/epochs"] < 5
    assert len(log) < 5
    tiny, _, before, after = _update(cfg.replace(target_kl=1e-12))
    assert tiny["ppo/epochs"] == 0.5  # one minibatch of the first epoch stepped, the second stopped
    assert not torch.equal(before[0], after[0])


def test_value_only_updates_leave_the_policy_as_it_is():
    cfg = make_train_config("paper", amat={"embed_dim": 32}, epochs=2, minibatches=2, lr=1e-3)
    _, _, before, after = _update(cfg, value_only=True)
    assert torch.equal(before[0], after[0])  # embedder, encoder, decoder, policy head untouched
    assert not torch.equal(before[1], after[1])  # the value head learns


def test_lr_decays_over_the_iterations_or_the_time_budget_whichever_ends_first():
    cfg = make_train_config("tiny", iterations=100)
    optim = cfg.optim
    assert lr_factor(1, optim, 1e6) == 1.0 and lr_factor(51, optim, 0.0) == pytest.approx(0.5)
    assert lr_factor(101, optim, 0.0) == 0.0
    timed = cfg.replace(budget_minutes=10.0).optim
    assert lr_factor(1, timed, 150.0) == pytest.approx(0.75)  # 2.5 of 10 minutes
    assert lr_factor(91, timed, 60.0) == pytest.approx(0.1)  # the iterations run out first
    assert lr_factor(2, timed, 900.0) == 0.0


def test_bad_step_control_values_are_refused():
    with pytest.raises(ValueError, match="target_kl"):
        make_train_config("tiny", target_kl=-1.0)
    with pytest.raises(ValueError, match="budget_minutes"):
        make_train_config("tiny", budget_minutes="ten")
    with pytest.raises(ValueError, match="warm_start"):
        make_train_config("tiny", warm_start="dijkstra")
    with pytest.raises(ValueError, match="value_warmup_iterations"):
        make_train_config("tiny", value_warmup_iterations=-2)
    with pytest.raises(ValueError, match="collector 'local'"):
        make_train_config("tiny", warm_start="nearest", collector="ray")


def test_precision_auto_follows_the_cpu_and_bf16_reaches_every_gradient(monkeypatch):
    from catmip_rl.training import ppo

    monkeypatch.setattr(ppo, "native_bf16", lambda: True)
    assert ppo.use_bf16("auto", "cpu") and not ppo.use_bf16("fp32", "cpu")
    monkeypatch.setattr(ppo, "native_bf16", lambda: False)
    assert not ppo.use_bf16("auto", "cpu") and ppo.use_bf16("bf16", "cpu")
    assert not ppo.use_bf16("auto", "cuda")
    with pytest.raises(ValueError, match="precision"):
        make_train_config("tiny", precision="fp16")
    cfg = make_train_config("paper", amat={"embed_dim": 32}, epochs=1, minibatches=1, lr=1e-3)
    fp32, _, before, after32 = _update(cfg)
    bf16, _, _, after16 = _update(cfg, bf16=True)  # the update of precision "bf16"
    # bf16 autocast moves the same parameters by about the same amount (not bitwise: bf16 rounding)
    step32, step16 = after32[0] - before[0], after16[0] - before[0]
    assert torch.isfinite(step16).all() and step16.abs().sum() > 0
    assert torch.nn.functional.cosine_similarity(step32, step16, dim=0) > 0.9
    assert bf16["loss/value"] == pytest.approx(fp32["loss/value"], rel=0.05)


def test_auto_precision_measures_and_takes_bf16_only_when_clearly_faster(monkeypatch, tmp_path):
    import json

    from catmip_rl.training import ppo
    from catmip_rl.training.train import train

    model = shaken_model(AmatConfig(embed_dim=32)).train()
    batch = _batch(worlds=2)
    kw = ppo.loss_kwargs(make_train_config("tiny").loss, False)
    timing = ppo.measure_bf16(model, batch, kw, events=8, repeats=1)
    assert timing["fp32_s"] > 0 and timing["bf16_s"] > 0
    assert all(p.grad is None for p in model.parameters())
    monkeypatch.setattr(ppo, "native_bf16", lambda: True)
    for fp32_s, bf16_s, expected in ((1.0, 0.5, True), (1.0, 0.95, False)):
        monkeypatch.setattr(ppo, "measure_bf16", lambda *a, t=(fp32_s, bf16_s), **k: dict(
            fp32_s=t[0], bf16_s=t[1]))  # fmt: skip
        assert ppo.choose_bf16("auto", "cpu", model, batch, kw)[0] is expected
    assert ppo.choose_bf16("fp32", "cpu", model, batch, kw)[0] is False
    train(
        make_train_config("tiny", precision="auto", iterations=1, eval_every=0),
        tmp_path / "r",
        progress=False,
    )
    decision = json.loads((tmp_path / "r" / "precision.json").read_text())
    assert decision["bf16"] is False and decision["fp32_s"] == 1.0  # the patched measurement decided


@pytest.mark.slow
def test_a_resumed_run_keeps_the_precision_auto_chose(monkeypatch, tmp_path):
    import json

    from catmip_rl.training import ppo
    from catmip_rl.training.train import train

    monkeypatch.setattr(ppo, "native_bf16", lambda: True)
    monkeypatch.setattr(ppo, "measure_bf16", lambda *a, **k: {"fp32_s": 1.0, "bf16_s": 0.5})
    cfg = make_train_config("tiny", precision="auto", iterations=1, eval_every=0)
    train(cfg, tmp_path / "r", progress=False)
    saved = torch.load(tmp_path / "r" / "checkpoints" / "latest.pt", weights_only=False)
    assert saved["bf16"] is True
    # the machine now measures the other way: the resumed run does not measure again, nor switch
    monkeypatch.setattr(ppo, "measure_bf16", lambda *a, **k: {"fp32_s": 0.5, "bf16_s": 1.0})
    train(cfg.replace(iterations=2), tmp_path / "r", resume=True, progress=False)
    assert torch.load(tmp_path / "r" / "checkpoints" / "latest.pt", weights_only=False)["bf16"] is True
    assert json.loads((tmp_path / "r" / "precision.json").read_text())["bf16"] is True


def test_a_run_resumed_on_another_kind_of_machine_chooses_its_precision_again(monkeypatch, tmp_path):
    import json

    from catmip_rl.store.checkpoint import atomic_torch_save
    from catmip_rl.training import ppo
    from catmip_rl.training.train import train

    monkeypatch.setattr(ppo, "native_bf16", lambda: True)
    monkeypatch.setattr(ppo, "measure_bf16", lambda *a, **k: {"fp32_s": 1.0, "bf16_s": 0.5})
    cfg = make_train_config("tiny", precision="auto", iterations=1, eval_every=0)
    latest = tmp_path / "r" / "checkpoints" / "latest.pt"
    train(cfg, tmp_path / "r", progress=False)
    saved = torch.load(latest, weights_only=False)
    assert saved["bf16"] is True and saved["bf16_machine"] == {"device": "cpu", "native_bf16": True}
    # a CPU without native bf16 (emulated: many times slower): "auto" resolves to fp32 there
    monkeypatch.setattr(ppo, "native_bf16", lambda: False)
    train(cfg.replace(iterations=2), tmp_path / "r", resume=True, progress=False)
    saved = torch.load(latest, weights_only=False)
    assert saved["bf16"] is False and saved["bf16_machine"] == {"device": "cpu", "native_bf16": False}
    assert json.loads((tmp_path / "r" / "precision.json").read_text())["native_bf16"] is False
    # a checkpoint from before bf16_machine, its choice made on a GPU: a CPU chooses again (measures)
    monkeypatch.setattr(ppo, "native_bf16", lambda: True)
    del saved["bf16_machine"]
    saved["config"] = json.dumps(json.loads(saved["config"]) | {"device": "cuda"})
    atomic_torch_save(saved, latest)
    train(cfg.replace(iterations=3), tmp_path / "r", resume=True, progress=False)
    assert torch.load(latest, weights_only=False)["bf16"] is True
    assert json.loads((tmp_path / "r" / "precision.json").read_text())["bf16_s"] == 0.5
