"""Asynchronous GAE: advantages along each robot's own sequence of activations.

The design: docs/design.md#asynchronous-gae.

Robot i's k-th macro-action starts at its k-th activation (event row ``t_k``) and lasts ``dt_k`` ticks,
until its next activation (or the end of the episode); its reward ``R_k`` is everything it collected in
between, discounted inside the interval by gamma per tick since the activation. With values ``V_k``::

    delta_k = R_k + gamma^dt_k * V_{k+1} - V_k
    A_k     = delta_k + (gamma^dt_k * lambda) * A_{k+1}

Each robot's last macro-action of an episode gets ``A_K = R_K - V_K`` (the return stops there: no
bootstrap). A rescue (termination) completes every robot's current macro-action, so after a rescue the
last one IS trained on: it holds the success reward, and for the rescuer it is the move that reached
the target. A macro-action cut off by the horizon (truncation) is unfinished and is not trained on.
Value targets are the lambda-returns ``A_k + V_k``.

:func:`build_batch` runs it on a collector's rollout and gives PPO its flat :class:`SampleBatch`, with
value targets normalised by :class:`ValueNorm` (the value head predicts normalised values).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from numba import njit

from catmip_rl.amat.inputs import one_hot_class
from catmip_rl.training.collect import Rollout

__all__ = ["async_gae", "ValueNorm", "SampleBatch", "build_batch", "explained_variance"]


@njit(cache=True)
def async_gae(
    active: np.ndarray,  # (T, B, N) bool: robot decides at event row t
    valid: np.ndarray,  # (T, B) bool: row t of world b is a real event
    values: np.ndarray,  # (T, B, N) float: V at each decision (denormalised)
    ma_return: np.ndarray,  # (T, B, N) float: return of the macro-action ending at row t (where active)
    ma_ticks: np.ndarray,  # (T, B, N) int: its duration in ticks
    final_return: np.ndarray,  # (B, N) float: return of each robot's last macro-action
    terminated: np.ndarray,  # (B,) bool: the episode ended in a rescue (not at the horizon)
    gamma: float,
    lam: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Returns (advantages, lambda-returns, trainable) of shape (T, B, N); trainable marks every
    activation whose macro-action finished: all of a rescued world's, all but each robot's last one of
    a truncated world's."""
    t_max, b_max, n_max = active.shape
    adv = np.zeros(active.shape, np.float64)
    ret = np.zeros(active.shape, np.float64)
    trainable = np.zeros(active.shape, np.bool_)
    rows = np.empty(t_max, np.int64)
    for b in range(b_max):
        for i in range(n_max):
            k = 0
            for t in range(t_max):
                if valid[t, b] and active[t, b, i]:
                    rows[k] = t
                    k += 1
            if k == 0:
                continue
            # the last macro-action: the return stops at the episode's end; a rescue completed it
            last = rows[k - 1]
            a_next = final_return[b, i] - values[last, b, i]
            adv[last, b, i] = a_next
            ret[last, b, i] = a_next + values[last, b, i]
            trainable[last, b, i] = terminated[b]
            v_next = values[last, b, i]
            for j in range(k - 2, -1, -1):
                t = rows[j]
                t_next = rows[j + 1]
                disc = gamma ** ma_ticks[t_next, b, i]
                delta = ma_return[t_next, b, i] + disc * v_next - values[t, b, i]
                a = delta + disc * lam * a_next
                adv[t, b, i] = a
                ret[t, b, i] = a + values[t, b, i]
                trainable[t, b, i] = True
                a_next = a
                v_next = values[t, b, i]
    return adv, ret, trainable


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
    label: torch.Tensor | None = None  # (M, N) long: the rescue rule's or anchor's action, -1 = none
    neighbourhood: torch.Tensor | None = None  # (M, N) long communication component (the cell-goal model's)
    state: torch.Tensor | None = None  # (M, 5+C, H, W) uint8 the true state (a model with critic "state")
    hint: torch.Tensor | None = None  # (M, N) long: the proposals (AmatConfig.hint), -1 none

    def __len__(self) -> int:
        return self.action.shape[0]

    def map(self, fn: Callable[[torch.Tensor], torch.Tensor]) -> SampleBatch:
        """A batch of ``fn(field)`` for every field that is set (optional fields stay None)."""
        return SampleBatch(**{k: None if v is None else fn(v) for k, v in self.__dict__.items()})

    def index(self, idx: torch.Tensor) -> SampleBatch:
        return self.map(lambda v: v[idx])

    def to(self, device) -> SampleBatch:
        return self.map(lambda v: v.to(device))


def build_batch(
    r: Rollout, value_norm: ValueNorm, gamma: float, lam: float, n_classes: int, device: torch.device
) -> tuple[SampleBatch, dict[str, float]]:
    """Async GAE on a rollout and the flat sample batch (rows = valid events), with ``samples`` (trainable
    robot decisions) and ``ppo/explained_variance`` (of the returns by the values that predicted them,
    1 - Var(R - V) / Var(R) over the trainable decisions; NaN with fewer than two)."""
    values = value_norm.denormalize(torch.from_numpy(r.value).double()).numpy()
    adv, ret, trainable = async_gae(
        r.active,
        r.valid,
        values,
        r.ma_return,
        r.ma_ticks.astype(np.int64),
        r.final_return,
        r.terminated,
        gamma,
        lam,
    )
    rows = r.valid
    explained = explained_variance(ret[rows][trainable[rows]], values[rows][trainable[rows]])
    ret_t = torch.from_numpy(ret[rows]).float()
    train_t = torch.from_numpy(trainable[rows])
    if train_t.any():
        value_norm.update(ret_t[train_t])
    adv_t = torch.from_numpy(adv[rows]).float()
    if train_t.sum() > 1:
        a = adv_t[train_t]
        adv_t = (adv_t - a.mean()) / (a.std() + 1e-8)
    batch = SampleBatch(
        global_map=torch.from_numpy(r.global_map[rows]),
        local_map=torch.from_numpy(r.local_map[rows]),
        agent_class=one_hot_class(r.agent_class[rows], n_classes),
        neighbourhood=torch.from_numpy(r.neighbourhood[rows]),
        action_mask=torch.from_numpy(r.action_mask[rows]),
        order=torch.from_numpy(r.order[rows]),
        action=torch.from_numpy(r.action[rows]),
        log_prob=torch.from_numpy(r.log_prob[rows]),
        value=torch.from_numpy(r.value[rows]),
        advantage=adv_t,
        target=value_norm.normalize(ret_t),
        trainable=train_t,
        label=None if r.label is None else torch.from_numpy(r.label[rows]),
        state=None if r.state is None else torch.from_numpy(r.state[rows]),
        hint=torch.from_numpy(r.hint[rows]),
    ).to(device)
    return batch, {"samples": float(train_t.sum()), "ppo/explained_variance": explained}


def explained_variance(returns: np.ndarray, values: np.ndarray) -> float:
    """1 - Var(returns - values) / Var(returns): 1 when the values predict the returns, 0 when they do
    no better than their mean, below 0 when worse; NaN for fewer than two returns or constant returns."""
    if returns.size < 2 or np.var(returns) == 0:
        return float("nan")
    return float(1.0 - np.var(returns - values) / np.var(returns))
