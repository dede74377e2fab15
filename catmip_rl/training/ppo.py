"""PPO for AMAT (docs/design.md#ppo-recipe): clipped policy loss over active robots, clipped Huber value
loss on normalised values, entropy bonus, advantage normalisation.

The loss is a few lines on purpose (``ppo_loss``); ``tests/rl/test_ppo.py`` checks that its policy term
equals TorchRL's ``ClipPPOLoss`` with the
:class:`~catmip_rl.adapters.torchrl_actor.AmatActor` on the same batch.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from catmip_rl.amat.model import AMAT

__all__ = ["ValueNorm", "SampleBatch", "ppo_loss", "accumulate_gradients"]


class ValueNorm(torch.nn.Module):
    """Running mean / variance of value targets (exponential moving average with debiasing, as in
    MAPPO); the value head predicts normalised values."""

    def __init__(self, beta: float = 0.99999, eps: float = 1e-5) -> None:
        super().__init__()
        self.beta, self.eps = beta, eps
        self.register_buffer("mean", torch.zeros((), dtype=torch.float64))
        self.register_buffer("mean_sq", torch.zeros((), dtype=torch.float64))
        self.register_buffer("debias", torch.zeros((), dtype=torch.float64))

    def _stats(self) -> tuple[torch.Tensor, torch.Tensor]:
        d = self.debias.clamp_min(self.eps)
        mean, mean_sq = self.mean / d, self.mean_sq / d
        return mean, (mean_sq - mean**2).clamp_min(1e-2)

    @torch.no_grad()
    def update(self, x: torch.Tensor) -> None:
        x = x.double()
        w = self.beta
        self.mean.mul_(w).add_(x.mean() * (1 - w))
        self.mean_sq.mul_(w).add_((x**2).mean() * (1 - w))
        self.debias.mul_(w).add_(1 - w)

    def normalize(self, x: torch.Tensor) -> torch.Tensor:
        mean, var = self._stats()
        return ((x.double() - mean) / var.sqrt()).to(x.dtype)

    def denormalize(self, x: torch.Tensor) -> torch.Tensor:
        mean, var = self._stats()
        return (x.double() * var.sqrt() + mean).to(x.dtype)


@dataclass
class SampleBatch:
    """Flat training samples: one row = one decision event of one world (all robots)."""

    global_map: torch.Tensor  # (M, N, 5+C, H, W) uint8
    local_map: torch.Tensor  # (M, N, 4+C, L, L) uint8
    agent_class: torch.Tensor  # (M, N, C) float
    action_mask: torch.Tensor  # (M, N, A) bool
    order: torch.Tensor  # (M, N) long
    action: torch.Tensor  # (M, N) long
    log_prob: torch.Tensor  # (M, N) old log-probs
    value: torch.Tensor  # (M, N) old normalised values
    advantage: torch.Tensor  # (M, N) (normalised over trainable entries)
    target: torch.Tensor  # (M, N) normalised value targets
    trainable: torch.Tensor  # (M, N) bool: active robots whose macro-action finished
    rescue_label: torch.Tensor | None = None  # (M, N) long: the rescue rule's window action, -1 = none

    def __len__(self) -> int:
        return self.action.shape[0]

    def map(self, fn: Callable[[torch.Tensor], torch.Tensor]) -> SampleBatch:
        """A batch of ``fn(field)`` for every field that is set (optional fields stay None)."""
        return SampleBatch(**{k: None if v is None else fn(v) for k, v in self.__dict__.items()})

    def index(self, idx: torch.Tensor) -> SampleBatch:
        return self.map(lambda v: v[idx])

    def to(self, device) -> SampleBatch:
        return self.map(lambda v: v.to(device))


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
    rescue_coef: float = 0.0,
    count: torch.Tensor | float | None = None,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """Total loss and its parts; every term averages over trainable (active, finished) robots only.

    ``rescue_coef`` > 0 adds an auxiliary cross-entropy toward ``batch.rescue_label`` (the rescue rule's
    window action, for rescuers that know the target; -1 elsewhere), summed over the labelled trainable
    robots and divided by the same count (``TrainConfig.rescue_coef``; 0 is the paper's loss).

    ``count`` replaces the number of trainable robots as the denominator: with the count of a whole
    minibatch, the losses (and parts) of its micro-batches add up to the minibatch's.
    """
    obs = {"global_map": batch.global_map, "local_map": batch.local_map, "agent_class": batch.agent_class}
    sel = batch.trainable.bool()  # the loss reads these robots only: logits and values of them alone
    logits, values = model.score(
        model.embed(obs), batch.action, batch.order, batch.agent_class, sel, batch.action_mask
    )  # (K, A), (K, 1)
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
    rescue_loss = torch.zeros((), device=loss.device)
    if rescue_coef > 0 and batch.rescue_label is not None:
        label = batch.rescue_label[sel]
        has = label >= 0
        rescue_loss = -logp_all[has].gather(-1, label[has][:, None]).sum() / count
        loss = loss + rescue_coef * rescue_loss
    with torch.no_grad():
        stats = {
            "loss/policy": policy_loss.detach(),
            "loss/value": value_loss.detach(),
            "loss/entropy": entropy.detach(),
            "loss/rescue": rescue_loss.detach(),
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
    (``catmip_rl.training.precision``)."""
    sums: dict[str, float] = {}
    device = batch.action.device.type
    for part in parts:
        with torch.autocast(device, dtype=torch.bfloat16, enabled=bf16):
            loss, stats = ppo_loss(model, batch.index(part), **loss_kwargs, count=count)
        loss.backward()
        for k, v in stats.items():
            sums[k] = sums.get(k, 0.0) + float(v)
    return sums
