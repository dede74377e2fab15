"""Thin TorchRL wrappers around :class:`~catmip_rl.amat.model.AMAT`: the actor and the critic.

* :class:`AmatActor` — ``forward(td)`` embeds, encodes and decodes the active robots autoregressively
  (sampling, or argmax under ``set_interaction_type("deterministic")`` / ``deterministic=True``), and
  writes actions, log-probs, values and the decision order; ``get_dist(td)`` re-scores the *stored*
  actions in one teacher-forced pass and returns a masked categorical over ``(B, N)`` — what TorchRL's
  ``ClipPPOLoss`` calls.
* :class:`AmatCritic` — the encoder's per-token values.

Keys are those of :mod:`catmip_rl.adapters.keys`.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import InteractionType, TensorDictModuleBase
from tensordict.nn.probabilistic import interaction_type
from torchrl.modules import MaskedCategorical

from catmip_rl.adapters import keys as K
from catmip_rl.amat.model import AMAT, decision_order

__all__ = ["AmatActor", "AmatCritic"]


def _obs(td: TensorDictBase) -> dict[str, torch.Tensor]:
    """The model's inputs of :data:`~catmip_rl.adapters.keys.AMAT_KEYS` that ``td`` holds (a window
    model reads the first three; a cell-goal model the neighbourhood too, and the hint if it has one)."""
    parts = {key[-1]: td.get(key, None) for key in K.AMAT_KEYS}
    return {name: value for name, value in parts.items() if value is not None}


def _padding(td: TensorDictBase) -> torch.Tensor | None:
    return td.get(K.PADDING, None)


class AmatActor(TensorDictModuleBase):
    """Samples goals for the active robots; re-scores stored goals for the PPO loss."""

    def __init__(self, model: AMAT, deterministic: bool | None = None) -> None:
        super().__init__()
        self.model = model
        self.deterministic = deterministic
        self.in_keys = [*K.AMAT_KEYS, K.ACTION_MASK, K.ACTIVE]
        self.out_keys = [K.ACTION, K.LOG_PROB, K.VALUE, K.ORDER]

    def _is_deterministic(self) -> bool:
        if self.deterministic is not None:
            return self.deterministic
        return interaction_type() in (InteractionType.DETERMINISTIC, InteractionType.MODE)

    @torch.no_grad()
    def forward(self, td: TensorDictBase) -> TensorDictBase:
        active, padding = td.get(K.ACTIVE), _padding(td)
        if padding is not None:
            active = active & ~padding
        rep, values = self.model.encode(self.model.embed(_obs(td)), padding)
        order = decision_order(active, padding)
        actions, log_probs = self.model.decode_autoregressive(
            rep, td.get(K.ACTION_MASK), order, active, td.get(K.AGENT_CLASS), self._is_deterministic()
        )
        td.set(K.ACTION, actions)
        td.set(K.LOG_PROB, log_probs)
        td.set(K.VALUE, values)
        td.set(K.ORDER, order)
        return td

    def get_dist(self, td: TensorDictBase) -> MaskedCategorical:
        """Masked categorical over (B, N) from teacher-forced logits of the stored actions and order."""
        rep, _ = self.model.encode(self.model.embed(_obs(td)), _padding(td))
        mask = td.get(K.ACTION_MASK).bool()
        logits = self.model.decode_parallel(
            rep, td.get(K.ACTION), td.get(K.ORDER), td.get(K.AGENT_CLASS), mask
        )
        return MaskedCategorical(logits=logits, mask=mask)


class AmatCritic(TensorDictModuleBase):
    """Per-robot values (B, N, 1) from the encoder's value head (shares the model with the actor)."""

    def __init__(self, model: AMAT) -> None:
        super().__init__()
        if model.state_critic is not None:  # its value head was never trained
            raise ValueError(
                "this AMAT's critic is its state critic (AmatConfig.critic 'state', trained by catmip "
                "train's collector), not the encoder's value head: AmatCritic needs a model with critic "
                "'encoder'"
            )
        self.model = model
        self.in_keys = list(K.AMAT_KEYS)
        self.out_keys = [K.VALUE]

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        _, values = self.model.encode(self.model.embed(_obs(td)), _padding(td))
        td.set(K.VALUE, values)
        return td
