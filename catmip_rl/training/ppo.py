"""PPO for AMAT (docs/design.md#ppo-recipe), the loss and the update in one place.

* :func:`ppo_loss` — clipped policy loss over active robots, clipped Huber value loss on normalised
  values, entropy bonus (a few lines on purpose: ``tests/rl/training/test_ppo.py`` checks that its policy term
  equals TorchRL's ``ClipPPOLoss`` with :class:`~catmip_rl.adapters.torchrl_actor.AmatActor` on the same
  batch); :func:`accumulate_gradients` — its backward over a minibatch's micro-batches;
* :func:`ppo_update` — epochs over minibatches of one iteration's batch
  (:class:`~catmip_rl.training.gae.SampleBatch`), one Adam step each (the gradients computed here or by
  ``parallel_update``'s helper processes), the epochs stopped at the first minibatch whose approx-KL
  exceeds ``optim.target_kl``;
* :func:`make_optimizer`, :func:`lr_factor`, :func:`set_lr` — the optimiser and the learning-rate
  schedule from a TrainConfig's ``optim`` section, :func:`loss_kwargs` — the loss's settings from its
  ``loss`` section (:mod:`~catmip_rl.training.sections`);
  :func:`choose_bf16` — the update's precision (below).

Precision on CPU: float32, or bfloat16 autocast where the CPU has it natively. On CPUs with native bf16
instructions (AVX-512 BF16, AMX) a training step under bf16 autocast measured 1.6x the float32
throughput; on AVX2-only CPUs torch emulates bf16 and the same step ran 14x slower (docs/speed.md).
Native bf16 is not enough either: a Task-1 update (d = 64) stopped early by the KL target, on
minibatches of a few hundred events, ran only ~4 % faster in bf16. ``precision="auto"`` therefore
measures both on the run's first batch where the CPU reports native bf16 and takes bf16 only if it is
at least 10 % faster (:func:`choose_bf16`). Parameters, optimiser state, losses and the sparse global
convolution stay float32 either way.
"""

from __future__ import annotations

import platform
import time
from functools import cache
from typing import Any

import torch
import torch.nn.functional as F

from catmip_rl.amat.model import AMAT, INVALID_LOGIT
from catmip_rl.training.config import PRECISIONS
from catmip_rl.training.gae import SampleBatch
from catmip_rl.training.sections import LossSection, OptimSection

__all__ = [
    "ppo_loss",
    "accumulate_gradients",
    "make_optimizer",
    "set_lr",
    "critic_prefix",
    "loss_kwargs",
    "ppo_update",
    "lr_factor",
    "measure_bf16",
    "choose_bf16",
    "native_bf16",
    "precision_machine",
    "use_bf16",
]


def huber(x: torch.Tensor, delta: float) -> torch.Tensor:
    return F.huber_loss(x, torch.zeros_like(x), reduction="none", delta=delta)


def ppo_loss(
    model: AMAT,
    batch: SampleBatch,
    clip: float = 0.05,
    value_clip: float = 0.05,
    huber_delta: float = 10.0,
    entropy_coef: float = 0.01,
    value_coef: float = 1.0,
    label_coef: float = 0.0,
    count: torch.Tensor | float | None = None,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """Total loss and its parts; every term averages over trainable (active, finished) robots only.

    ``label_coef`` > 0 adds an auxiliary cross-entropy toward ``batch.label``: the rescue rule's window
    action for rescuers that know the target (``TrainConfig.rescue_coef``), or the anchor planner's goal
    (``TrainConfig.anchor_coef``); -1 where there is no label. It is summed over the labelled trainable
    robots and divided by the same count (0 is the paper's loss; its part is logged as "loss/rescue").

    ``count`` replaces the number of trainable robots as the denominator: with the count of a whole
    minibatch, the losses (and parts) of its micro-batches add up to the minibatch's.
    """
    parts = ("global_map", "local_map", "agent_class", "neighbourhood", "hint")
    obs = {k: getattr(batch, k) for k in parts if getattr(batch, k) is not None}  # the window model's: 3
    sel = batch.trainable.bool()  # the loss reads these robots only: logits and values of them alone
    logits, values = model.score(
        model.embed(obs), batch.action, batch.order, batch.agent_class, sel, batch.action_mask
    )  # (K, A), (K, 1)
    if model.state_critic is not None:  # PPO's values from the true state (amat.critic)
        values = model.state_critic(batch.state, batch.global_map, batch.agent_class, sel)
    action, old_logp, adv = batch.action[sel], batch.log_prob[sel], batch.advantage[sel]
    logp_all = torch.log_softmax(logits.float(), -1)  # (K, A)
    logp = logp_all.gather(-1, action[:, None])[:, 0]
    count = sel.sum().clamp_min(1).float() if count is None else count
    ratio = torch.exp(logp - old_logp)
    surrogate = torch.min(ratio * adv, ratio.clamp(1 - clip, 1 + clip) * adv)
    policy_loss = -surrogate.sum() / count
    probs = logp_all.exp()
    entropy = -(torch.where(batch.action_mask[sel].bool(), probs * logp_all, 0.0)).sum() / count
    v, old_v, target = values[:, 0].float(), batch.value[sel], batch.target[sel]
    v_clipped = old_v + (v - old_v).clamp(-value_clip, value_clip)
    value_loss = torch.max(huber(v - target, huber_delta), huber(v_clipped - target, huber_delta))
    value_loss = value_loss.sum() / count
    loss = policy_loss + value_coef * value_loss - entropy_coef * entropy
    label_loss = torch.zeros((), device=loss.device)
    if label_coef > 0 and batch.label is not None:
        label = batch.label[sel]
        has = label >= 0
        column = label[has][:, None]
        allowed = logits[has].gather(-1, column)[:, 0] > INVALID_LOGIT / 2  # not scored outside the mask
        label_loss = -logp_all[has].gather(-1, column)[:, 0][allowed].sum() / count
        loss = loss + label_coef * label_loss
    with torch.no_grad():
        stats = {
            "loss/policy": policy_loss.detach(),
            "loss/value": value_loss.detach(),
            "loss/entropy": entropy.detach(),
            "loss/rescue": label_loss.detach(),  # the name the logs have always had
            "ppo/approx_kl": ((ratio - 1) - (logp - old_logp)).sum() / count,
            "ppo/clip_fraction": ((ratio - 1).abs() > clip).float().sum() / count,
        }
    return loss, stats


def accumulate_gradients(
    model: AMAT, batch: SampleBatch, parts, count: torch.Tensor | float, bf16: bool = False, **loss_kwargs
) -> dict[str, float]:
    """Backward of ``ppo_loss`` over the micro-batches ``parts`` (index tensors into ``batch``), each
    averaged with the minibatch's ``count``, into the model's .grad (added to what is there); returns
    the loss parts summed over the micro-batches. ``bf16`` runs the forward under bfloat16 autocast
    (the module's docstring says when that pays)."""
    sums: dict[str, float] = {}
    device = batch.action.device.type
    for part in parts:
        with torch.autocast(device, dtype=torch.bfloat16, enabled=bf16):
            loss, stats = ppo_loss(model, batch.index(part), **loss_kwargs, count=count)
        loss.backward()
        for k, v in stats.items():
            sums[k] = sums.get(k, 0.0) + float(v)
    return sums


def critic_prefix(model: AMAT) -> str:
    """The names' prefix of PPO's critic's parameters: the state critic's, or else the value head's."""
    return "state_critic." if model.state_critic is not None else "value_head."


def make_optimizer(model: AMAT, optim: OptimSection) -> torch.optim.Adam:
    """Adam with the section's lr and eps, fused (one kernel for all parameters: ~6x faster a step on CPU
    than the per-parameter loop, the same arithmetic); with ``optim.critic_lr`` the critic's parameters are
    a second group (``"critic": True``) at that rate."""
    if not optim.critic_lr:
        return torch.optim.Adam(model.parameters(), lr=optim.lr, eps=optim.adam_eps, fused=True)
    critic = critic_prefix(model)
    groups = [{"params": [], "critic": False}, {"params": [], "lr": optim.critic_lr, "critic": True}]
    for name, param in model.named_parameters():
        groups[name.startswith(critic)]["params"].append(param)
    return torch.optim.Adam(groups, lr=optim.lr, eps=optim.adam_eps, fused=True)


def set_lr(opt: torch.optim.Optimizer, optim: OptimSection, factor: float) -> None:
    """The learning rates ``factor`` of the section's: ``optim.critic_lr`` for the critic's group (if any)."""
    for group in opt.param_groups:
        base = optim.critic_lr if group.get("critic") else optim.lr
        group["lr"] = base * factor


def loss_kwargs(loss: LossSection, bf16: bool = False) -> dict[str, float | bool]:
    """The ``accumulate_gradients`` arguments of a ``loss`` section: ``ppo_loss`` coefficients, and bf16
    autocast or not (the update's precision, resolved: :func:`choose_bf16`, :func:`use_bf16`)."""
    return {
        "clip": loss.clip,
        "value_clip": loss.value_clip,
        "huber_delta": loss.huber_delta,
        "entropy_coef": loss.entropy_coef,
        "value_coef": loss.value_coef,
        "label_coef": loss.rescue_coef or loss.anchor_coef,  # the auxiliary label loss: rescue or anchor
        "bf16": bf16,
    }


def ppo_update(
    model: AMAT,
    opt: torch.optim.Optimizer,
    batch: SampleBatch,
    optim: OptimSection,
    loss: LossSection,
    gen: torch.Generator,
    parallel: Any = None,
    epoch_log: list[dict[str, float]] | None = None,
    value_only: bool = False,
    bf16: bool = False,
) -> dict[str, float]:
    """Up to ``optim.epochs`` passes over ``optim.minibatches`` minibatches of ``batch``, one Adam step
    each, on ``loss``'s loss (a TrainConfig's two sections), under bf16 autocast with ``bf16``; each
    minibatch's gradient is accumulated over micro-batches of ``optim.micro_batch`` events, by this process
    or, with ``parallel`` (a ``parallel_update.ParallelGradients`` of the same loss), shared with its
    helper processes. With ``optim.target_kl`` the epochs
    stop at the first minibatch whose approx-KL (before its step) exceeds it, without stepping.

    Returns the last minibatch's loss parts and gradient norm, ``ppo/epochs`` (epochs run, fractional
    when stopped inside one) and ``ppo/early_stop``; ``epoch_log`` receives one dict per epoch (its
    minibatches' mean loss parts, approx-KL and clip fraction). ``value_only`` steps the critic (the
    value head, or the state critic) alone (the value warm-up after an imitation warm start: the policy
    is left as it is)."""
    model.train()
    settings = loss_kwargs(loss, bf16)  # the loss's settings, once for the whole update
    params = [p for p in model.parameters() if p.requires_grad]
    critic = critic_prefix(model)
    frozen = [p for n, p in model.named_parameters() if not n.startswith(critic)] if value_only else []
    stats: dict[str, float] = {}
    if parallel is not None:
        parallel.set_batch(batch)
    steps, stopped = 0, False
    for epoch in range(optim.epochs):
        shuffle = optim.minibatches > 1
        perm = torch.randperm(len(batch), generator=gen) if shuffle else torch.arange(len(batch))
        epoch_sums: dict[str, float] = {}
        seen = 0
        for idx in perm.chunk(optim.minibatches):
            idx = idx.to(batch.action.device)
            count = batch.trainable[idx].sum().clamp_min(1).float()
            opt.zero_grad(set_to_none=True)
            parts = list(idx.split(optim.micro_batch)) if optim.micro_batch else [idx]
            if parallel is None:
                sums = accumulate_gradients(model, batch, parts, count, **settings)
            else:
                sums = parallel.backward(model, parts, count)
            seen += 1
            for k, v in sums.items():
                epoch_sums[k] = epoch_sums.get(k, 0.0) + v
            if optim.target_kl and sums["ppo/approx_kl"] > optim.target_kl:
                stopped = True
                stats = sums | {"ppo/grad_norm": float("nan")}
                break
            for p in frozen:
                p.grad = None  # Adam skips parameters without a gradient
            grad_norm = torch.nn.utils.clip_grad_norm_(params, optim.max_grad_norm)
            opt.step()
            steps += 1
            stats = sums | {"ppo/grad_norm": float(grad_norm)}
        if epoch_log is not None:
            epoch_log.append({"epoch": epoch + 1} | {k: v / seen for k, v in epoch_sums.items()})
        if stopped:
            break
    opt.zero_grad(set_to_none=True)
    return stats | {"ppo/epochs": steps / optim.minibatches, "ppo/early_stop": float(stopped)}


def lr_factor(iteration: int, optim: OptimSection, elapsed_s: float) -> float:
    """Linear decay to 0 over the run: over ``optim.iterations``, or over ``optim.budget_minutes`` of
    training if that runs out first (``iteration`` counts from 1; ``elapsed_s`` before it)."""
    progress = (iteration - 1) / optim.iterations
    if optim.budget_minutes:
        progress = max(progress, elapsed_s / (60.0 * optim.budget_minutes))
    return max(0.0, 1.0 - progress)


def measure_bf16(
    model: AMAT, batch: SampleBatch, settings: dict[str, Any], events: int = 512, repeats: int = 2
) -> dict[str, float]:
    """Seconds of one forward + backward of the PPO loss on the first ``events`` events of ``batch``,
    float32 and bf16 autocast (best of ``repeats`` after a warm-up each), the loss's ``settings``
    (:func:`loss_kwargs`) otherwise; the model's gradients are left cleared."""
    part = torch.arange(min(events, len(batch)), device=batch.action.device)
    count = batch.trainable[part].sum().clamp_min(1).float()
    out = {}
    for name, bf16 in (("fp32_s", False), ("bf16_s", True)):
        best = float("inf")
        for k in range(repeats + 1):
            model.zero_grad(set_to_none=True)
            t0 = time.perf_counter()
            accumulate_gradients(model, batch, [part], count, **(settings | {"bf16": bf16}))
            if k:  # the first run warms up (oneDNN primitives, allocator)
                best = min(best, time.perf_counter() - t0)
        out[name] = best
    model.zero_grad(set_to_none=True)
    return out


def choose_bf16(
    setting: str, device: str, model: AMAT, batch: SampleBatch, settings: dict[str, Any], events: int = 512
) -> tuple[bool, dict[str, Any]]:
    """(bf16 or not, what decided it) for ``TrainConfig.precision`` ``setting``: "auto" on a CPU with
    native bf16 measures both on this batch and takes bf16 only if it is at least 10 % faster;
    everything else as :func:`use_bf16`."""
    native = native_bf16()
    if setting != "auto" or not device.startswith("cpu") or not native:
        return use_bf16(setting, device), {"precision": setting, "native_bf16": native}
    timing = measure_bf16(model, batch, settings, events)
    bf16 = timing["bf16_s"] < 0.9 * timing["fp32_s"]
    return bf16, {"precision": setting, "native_bf16": True, **timing, "bf16": bf16}


_NATIVE_FLAGS = ("avx512_bf16", "amx_bf16")


@cache
def native_bf16() -> bool:
    """Whether this CPU executes bf16 natively (Linux: an ``avx512_bf16`` or ``amx_bf16`` flag in
    /proc/cpuinfo; elsewhere False)."""
    if platform.system() != "Linux":
        return False
    try:
        with open("/proc/cpuinfo") as f:
            flags = next((line for line in f if line.startswith("flags")), "")
    except OSError:
        return False
    return any(flag in flags.split() for flag in _NATIVE_FLAGS)


def precision_machine(device: str) -> dict[str, Any]:
    """What a precision choice depends on: the device's type and, on a CPU, whether it has native bf16
    (a checkpoint records it; a run resumed on another kind of machine chooses again)."""
    kind = torch.device(device).type
    return {"device": kind, "native_bf16": native_bf16() if kind == "cpu" else None}


def use_bf16(precision: str, device: str) -> bool:
    """Resolve a ``TrainConfig.precision`` for ``device`` by the CPU's flags: bf16 autocast or not."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {list(PRECISIONS)}, got {precision!r}")
    if not device.startswith("cpu"):
        return precision == "bf16"
    return precision == "bf16" or (precision == "auto" and native_bf16())
