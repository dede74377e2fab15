"""AMAT — the Asynchronous Multi-Agent Transformer (docs/design.md#amat), a plain ``torch.nn.Module``.

Shapes legend: ``B`` batch (worlds or samples), ``N`` robots (tokens), ``d`` embedding, ``A`` actions
(D*D window goals), ``C`` robot classes, ``S`` map side, ``L`` local map side, ``G`` pooled grid.

Data flow of one decision::

    obs --embed--> tokens (B, N, d) --encode--> rep (B, N, d), values (B, N, 1)
    rep --decode_autoregressive--> actions, log-probs of the active robots (rollout)
    rep, stored actions --decode_parallel--> logits (B, N, A) (teacher forcing, training)
    tokens, stored actions --score--> logits, values of selected robots only (the PPO loss)

Decision order: active robots first, then busy ones, then padding, each in ascending id
(:func:`decision_order`). Robot ``k`` of the order sees, through the decoder, the actions chosen by
robots ``0 .. k-1``; padding tokens are masked out of attention, never fed as zeros.

The transformer blocks and the decoder's key/value cache are in ``layers``; training on CPU runs the
global CNN through ``sparse_conv`` and attention through ``small_attention``.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from catmip_rl.amat.config import AmatConfig
from catmip_rl.amat.critic import StateCritic
from catmip_rl.amat.kernels.sparse_conv import global_conv_pool
from catmip_rl.amat.layers import BlockCache, DecoderBlock, EncoderBlock, as_float, layer_norm, linear

__all__ = ["AMAT", "decision_order", "gather_robots", "INVALID_LOGIT"]

INVALID_LOGIT = -1e10


def decision_order(active: torch.Tensor, padding: torch.Tensor | None = None) -> torch.Tensor:
    """(B, N) robot index at each decision position: active robots, then busy, then padding, each
    in ascending id."""
    n = active.shape[-1]
    ids = torch.arange(n, device=active.device).expand_as(active)
    rank = (~active).long() * n + ids  # active first
    if padding is not None:
        rank = rank + padding.long() * 2 * n
    return torch.argsort(rank, dim=-1)


class AMAT(nn.Module):
    """Embedder, encoder with per-token value head, macro-action embedder, causal decoder, policy
    head. Tensor-in / tensor-out; see the module docstring for the data flow."""

    def __init__(self, config: AmatConfig | None = None) -> None:
        super().__init__()
        cfg = self.config = config or AmatConfig()
        if cfg.goals != "window" and type(self) is AMAT:
            raise ValueError(
                f"AmatConfig.goals={cfg.goals!r} is amat.pointer.PointerAMAT: build it with make_model"
            )
        d, c, g, l = cfg.embed_dim, cfg.n_classes, cfg.pool, cfg.local_size
        # -- macro-observation embedder ---------------------------------------------------------
        self.global_conv = nn.Conv2d(cfg.global_channels, 32, 7, stride=1, padding=3)
        self.global_pool = nn.AdaptiveMaxPool2d(g)
        self.global_ln = nn.LayerNorm([32, g, g])
        self.local_conv1 = nn.Conv2d(cfg.local_channels, 64, 3, padding=1)
        self.local_ln1 = nn.LayerNorm([64, l, l])
        self.local_conv2 = nn.Conv2d(64, 32, 3, padding=1)
        self.local_ln2 = nn.LayerNorm([32, l, l])
        self.obs_fc1 = nn.Linear(32 * g * g + 32 * l * l, d)
        self.obs_ln = nn.LayerNorm(d)
        self.obs_fc2 = nn.Linear(d, d)
        self.class_enc = nn.Linear(c, d)
        # -- encoder ------------------------------------------------------------------------------
        self.enc_ln = nn.LayerNorm(d)
        self.enc_blocks = nn.ModuleList(EncoderBlock(d, cfg.n_heads) for _ in range(cfg.n_blocks))
        self.value_head = nn.Sequential(nn.Linear(d, d), nn.GELU(), nn.LayerNorm(d), nn.Linear(d, 1))
        # critic "state": PPO's values from the world's true state instead (amat.critic); built after
        # _init_weights' loop has run over the rest, so the paper's model draws the same weights
        self.state_critic: StateCritic | None = None
        # -- macro-action embedder and decoder -----------------------------------------------------
        self._build_decoder()
        self._init_weights()
        if cfg.critic == "state":
            self.state_critic = StateCritic(c)

    def _build_decoder(self) -> None:
        """The decoder and its policy head over the D*D window goals."""
        cfg, d = self.config, self.config.embed_dim
        self.action_enc = nn.Linear(cfg.num_actions + 1, d, bias=False)  # index 0: start token
        self.dec_class_enc = nn.Linear(cfg.n_classes, d)
        self.dec_ln = nn.LayerNorm(d)
        self.dec_blocks = nn.ModuleList(DecoderBlock(d, cfg.n_heads) for _ in range(cfg.n_blocks))
        self.policy_head = nn.Sequential(
            nn.Linear(d, d), nn.GELU(), nn.LayerNorm(d), nn.Linear(d, cfg.num_actions)
        )

    # -- initialisation ---------------------------------------------------------------------------
    def _activated_layers(self) -> set[nn.Module]:
        """Layers followed by an activation (directly or after a LayerNorm): initialised with gain sqrt(2)."""
        return {
            self.global_conv,
            self.local_conv1,
            self.local_conv2,
            self.obs_fc1,
            self.obs_fc2,
            self.class_enc,
            self.value_head[0],
            self.action_enc,
            self.dec_class_enc,
            self.policy_head[0],
        }

    def _init_weights(self) -> None:
        """Orthogonal weights, zero biases; gain sqrt(2) for layers followed by an activation (directly
        or after a LayerNorm), 0.01 for the rest (attention projections, second MLP layers, heads)."""
        activated = self._activated_layers()
        for block in [*self.enc_blocks, *self.dec_blocks]:
            activated.add(block.mlp[0])
        for m in self.modules():
            if isinstance(m, (nn.Linear, nn.Conv2d)):
                gain = math.sqrt(2.0) if m in activated else 0.01
                nn.init.orthogonal_(m.weight.view(m.weight.shape[0], -1), gain=gain)
                if m.bias is not None:
                    nn.init.zeros_(m.bias)

    # -- embedder ---------------------------------------------------------------------------------
    def embed(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        """Tokens (B, N, d) from macro-observations: ``global_map`` (B, N, 5+C, S, S), ``local_map``
        (B, N, 4+C, L, L) (uint8 with float = x * 0.25, or float), ``agent_class`` (B, N, C).

        Written with functional calls: ``nn.Module.__call__`` costs ~15 us per layer on the 2-core CPU,
        a tenth of a batch-1 decision.
        """
        gmap, lmap, cls = obs["global_map"], obs["local_map"], obs["agent_class"]
        b, n = gmap.shape[:2]
        if gmap.dtype == torch.uint8 and gmap.device.type == "cpu" and torch.is_grad_enabled():
            # training on CPU: sparse conv + pool with a winning-cell backward (amat.kernels.sparse_conv)
            g = global_conv_pool(gmap, self.global_conv.weight, self.global_conv.bias, self.config.pool)
        else:
            g = as_float(gmap).flatten(0, 1)  # (B*N, 5+C, S, S)
            g = F.conv2d(g, self.global_conv.weight, self.global_conv.bias, padding=3)  # (B*N, 32, S, S)
            g = _max_pool(g, self.config.pool)  # (B*N, 32, G, G)
        g = F.relu(layer_norm(g, self.global_ln), inplace=True).flatten(1)  # (B*N, 32 G^2)
        x = as_float(lmap).flatten(0, 1)  # (B*N, 4+C, L, L)
        x = F.conv2d(x, self.local_conv1.weight, self.local_conv1.bias, padding=1)
        # in place: LayerNorm's backward does not need its output
        x = F.relu(layer_norm(x, self.local_ln1), inplace=True)
        x = F.conv2d(x, self.local_conv2.weight, self.local_conv2.bias, padding=1)
        x = F.relu(layer_norm(x, self.local_ln2), inplace=True).flatten(1)  # (B*N, 32 L^2)
        w1, n_g = self.obs_fc1.weight, g.shape[1]  # two products instead of a concatenated input
        h = F.gelu(F.linear(x, w1[:, n_g:], self.obs_fc1.bias) + F.linear(g, w1[:, :n_g]))  # (B*N, d)
        h = F.gelu(linear(layer_norm(h, self.obs_ln), self.obs_fc2))
        return h.view(b, n, -1) + F.gelu(linear(cls.to(h.dtype), self.class_enc))  # (B, N, d)

    # -- encoder ----------------------------------------------------------------------------------
    def encode(
        self, tokens: torch.Tensor, key_padding_mask: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(rep (B, N, d), values (B, N, 1)). ``key_padding_mask`` (B, N) bool, True = padding."""
        allowed = None
        if key_padding_mask is not None:
            allowed = (~key_padding_mask)[:, None, None, :]  # (B, 1, 1, N)
        x = self.enc_ln(tokens)
        for block in self.enc_blocks:
            x = block(x, allowed)
        return x, self.value_head(x)

    # -- decoder ----------------------------------------------------------------------------------
    def _action_tokens(self, prev: torch.Tensor, cls: torch.Tensor) -> torch.Tensor:
        """Decoder input (B, T, d) from the previous robot's action index + 1 (0 = start) and the
        deciding robot's class one-hot."""
        emb = F.gelu(F.embedding(prev, self.action_enc.weight.t()))  # one-hot @ W == row lookup
        return self.dec_ln(emb + F.gelu(self.dec_class_enc(cls)))

    def _teacher_tokens(self, actions: torch.Tensor, order: torch.Tensor, cls: torch.Tensor) -> torch.Tensor:
        """Teacher-forced decoder input (B, N, d) in decision order: position k gets the stored action
        of the robot at position k - 1 (the start token at 0) and its own robot's class."""
        act_o = torch.gather(actions.clamp_min(0), 1, order)  # (B, N)
        prev = torch.cat([torch.zeros_like(act_o[:, :1]), act_o[:, :-1] + 1], dim=1)  # shifted, 0 = start
        return self._action_tokens(prev, gather_robots(cls, order))

    def decode_parallel(
        self,
        rep: torch.Tensor,  # (B, N, d) encoder output, robot order
        actions: torch.Tensor,  # (B, N) long, stored actions (busy robots: anything in range)
        order: torch.Tensor,  # (B, N) long, robot index at each decision position
        agent_class: torch.Tensor,  # (B, N, C)
        action_mask: torch.Tensor | None = None,  # (B, N, A) bool/int, 1 = allowed
    ) -> torch.Tensor:
        """Teacher-forced logits (B, N, A) in robot order, in one pass; masked actions get -1e10."""
        n = rep.shape[1]
        rep_o = gather_robots(rep, order)  # (B, N, d) decision order
        x = self._teacher_tokens(actions, order, agent_class.to(rep.dtype))
        causal = torch.ones(n, n, dtype=torch.bool, device=rep.device).tril()[None, None]
        for block in self.dec_blocks:
            x = block(x, rep_o, causal)
        logits_o = self.policy_head(x)  # (B, N, A)
        logits = torch.empty_like(logits_o).scatter_(1, order[..., None].expand_as(logits_o), logits_o)
        if action_mask is not None:
            logits = logits.masked_fill(~action_mask.bool(), INVALID_LOGIT)
        return logits

    @torch.no_grad()
    def decode_autoregressive(
        self,
        rep: torch.Tensor,  # (B, N, d)
        action_mask: torch.Tensor,  # (B, N, A)
        order: torch.Tensor,  # (B, N)
        active: torch.Tensor,  # (B, N) bool
        agent_class: torch.Tensor,  # (B, N, C)
        deterministic: bool = False,
        generator: torch.Generator | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Decode the active robots one after another with cached keys/values.

        Returns (actions (B, N) long, log_probs (B, N)); busy robots get their single allowed
        ("keep") action and log-prob 0. Only the first K = max #active positions are decoded.
        """
        b, n, d = rep.shape
        mask = action_mask.bool()
        n_active = active.sum(1)  # (B,)
        steps = int(n_active.max()) if b else 0
        actions = mask.to(torch.uint8).argmax(-1)  # busy robots: their keep action
        log_probs = rep.new_zeros(b, n)
        if steps == 0:
            return actions, log_probs
        order_a = order[:, :steps]  # (B, K): the first K positions hold the active robots
        rep_o = gather_robots(rep, order_a)  # (B, K, d)
        cls_tok = F.gelu(
            linear(gather_robots(agent_class.to(rep.dtype), order_a), self.dec_class_enc)
        )  # (B, K, d)
        mask_o = gather_robots(mask, order_a)  # (B, K, A)
        caches = [BlockCache(blk, rep_o) for blk in self.dec_blocks]
        emb = self.action_enc.weight.t()  # (A + 1, d): one-hot @ W == row lookup
        head = self.policy_head
        prev = torch.zeros(b, dtype=torch.long, device=rep.device)  # start token
        chosen = torch.empty(b, steps, dtype=torch.long, device=rep.device)
        chosen_lp = rep.new_empty(b, steps)
        for k in range(steps):
            x = layer_norm(F.gelu(emb[prev])[:, None] + cls_tok[:, k : k + 1], self.dec_ln)  # (B, 1, d)
            for cache in caches:
                x = cache.step(x, k)
            h = layer_norm(F.gelu(linear(x[:, 0], head[0])), head[2])
            logits = linear(h, head[3]).masked_fill_(~mask_o[:, k], INVALID_LOGIT)  # (B, A)
            logp_all = torch.log_softmax(logits, -1)
            if deterministic:
                a = logits.argmax(-1)
            else:
                a = torch.multinomial(logp_all.exp(), 1, generator=generator)[:, 0]
            chosen[:, k] = a
            chosen_lp[:, k] = logp_all.gather(1, a[:, None])[:, 0]
            prev = a + 1
        # write back in robot order, only where the k-th position is an active robot
        valid = torch.arange(steps, device=rep.device)[None, :] < n_active[:, None]  # (B, K)
        actions.scatter_(1, order_a, torch.where(valid, chosen, actions.gather(1, order_a)))
        log_probs.scatter_(1, order_a, torch.where(valid, chosen_lp, 0.0))
        return actions, log_probs

    # -- training ---------------------------------------------------------------------------------
    def score(
        self,
        tokens: torch.Tensor,  # (B, N, d) embedded macro-observations
        actions: torch.Tensor,  # (B, N) long, stored actions
        order: torch.Tensor,  # (B, N) long, robot index at each decision position
        agent_class: torch.Tensor,  # (B, N, C)
        select: torch.Tensor,  # (B, N) bool: the robots to score
        action_mask: torch.Tensor | None = None,  # (B, N, A) bool/int, 1 = allowed
        key_padding_mask: torch.Tensor | None = None,  # (B, N) bool, True = padding
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Teacher-forced logits (K, A) and values (K, 1) of the K selected robots, in the row-major
        order of ``select``: ``decode_parallel`` and ``encode`` at those robots, computed for them alone.

        Every robot is still a key of every attention; past the last attention of a stack, only the
        selected rows are computed (the output projection, LayerNorms, MLP and heads): with one block,
        the encoder's too, since only the selected robots' representations are then read. The PPO loss
        weighs only trainable robots, about half of a Task-2 batch's tokens.
        """
        b, n, d = tokens.shape
        if select.shape != (b, n) or order.shape != (b, n) or actions.shape != (b, n):
            raise ValueError(
                f"score: select {tuple(select.shape)}, order {tuple(order.shape)} and actions "
                f"{tuple(actions.shape)} must all be (B, N) = {(b, n)} for tokens {tuple(tokens.shape)}"
            )
        allowed = None if key_padding_mask is None else (~key_padding_mask)[:, None, None, :]
        rows = select.flatten().nonzero()[:, 0]  # (K,) flat robot-order indices
        one_block = len(self.dec_blocks) == 1  # the decoder reads the selected representations only
        x = self.enc_ln(tokens)
        last = len(self.enc_blocks) - 1
        for i, block in enumerate(self.enc_blocks):
            x = block(x, allowed, rows if one_block and i == last else None)
        rep_sel = x if one_block else x.flatten(0, 1)[rows]  # (K, d)
        values = self.value_head(rep_sel)
        # decoder, in decision order: the flat position of each selected robot
        pos = torch.empty_like(order).scatter_(1, order, torch.arange(n, device=order.device).expand(b, n))
        rows_o = (pos + torch.arange(b, device=order.device)[:, None] * n).flatten()[rows]
        if one_block:  # queries of unselected positions are never read: zeros
            rep_o = rep_sel.new_zeros(b * n, d).index_copy(0, rows_o, rep_sel).view(b, n, d)
        else:
            rep_o = gather_robots(x, order)
        y = self._teacher_tokens(actions, order, agent_class.to(tokens.dtype))
        causal = torch.ones(n, n, dtype=torch.bool, device=tokens.device).tril()[None, None]
        last = len(self.dec_blocks) - 1
        for j, block in enumerate(self.dec_blocks):
            y = block(y, rep_o, causal, rows_o if j == last else None)
        logits = self.policy_head(y)  # (K, A)
        if action_mask is not None:
            logits = logits.masked_fill(~action_mask.flatten(0, 1)[rows].bool(), INVALID_LOGIT)
        return logits, values

    # -- convenience ------------------------------------------------------------------------------
    def forward(self, obs: dict[str, torch.Tensor], key_padding_mask: torch.Tensor | None = None):
        """Embed + encode: (rep, values)."""
        return self.encode(self.embed(obs), key_padding_mask)


def _max_pool(x: torch.Tensor, g: int) -> torch.Tensor:
    """Adaptive max pool to g x g; two contiguous reductions when the side divides evenly."""
    n, c, hh, ww = x.shape
    if hh % g or ww % g:
        return F.adaptive_max_pool2d(x, g)
    return x.view(n, c, hh, g, ww // g).amax(-1).view(n, c, g, hh // g, g).amax(3)


def gather_robots(x: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """x (B, N, ...) reordered along dim 1 by index (B, K)."""
    idx = index.view(*index.shape, *([1] * (x.dim() - 2))).expand(*index.shape, *x.shape[2:])
    return torch.gather(x, 1, idx)
