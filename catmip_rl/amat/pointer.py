"""AMAT with goals anywhere on the map (``AmatConfig.goals == "cell"``): a pointer head over the cells.

The paper's AMAT chooses one of D*D goals around the robot. This model keeps its embedder, encoder and
autoregressive decoder over the robots and replaces the window head by a pointer: a fully
convolutional encoder turns the deciding robot's own maps into per-cell features, and the decoder's
output for that robot scores every cell against them. The action is the planners' cell action
``r * W + c`` (``EventEngine(goal_mode="cell")``), the same weights serve any map size and team, and a
rescuer that knows the target can go there in one decision.

Shapes legend as in ``model``, plus ``H, W`` the map, ``K`` selected robots, ``c`` cell channels.

    obs (+ "neighbourhood" (B, N)) --embed--> Embedded(tokens (B, N, d), cells)
    --encode--> Embedded(rep, cells), values --decode_autoregressive--> cell actions (B, N)

* **Inputs per cell** (``kernels.cell_fields``, from the observation alone): the robot's global map,
  its path distance to every cell and whether the cell is reachable; with ``AmatConfig.hint`` also the
  cell a planner proposes for the robot (``obs["hint"]``), which gets a learned logit bonus as well.
* **The mask** is the environment's mask narrowed to the cells a planner may choose, or the robot's
  own cell ("stay"): ``AmatConfig.cell_mask`` "known" (explored, free on its map and reachable: the
  frontier planners' goals) or "reachable" (unknown cells too: RRT's goals).
* **Neighbourhoods.** With ``obs["neighbourhood"]`` (the communication components, ``state.comp``) a
  robot attends only to its neighbourhood in the encoder and the decoder, and the decoding order runs
  through each neighbourhood separately: one batched pass is exactly each neighbourhood deciding on its
  own (decentralised execution), in training and in evaluation alike. Without it the team is one.
* **Previous decisions.** A robot's decoder input is the goal the previous robot of its neighbourhood
  chose (its offset from that robot); the pointer also sees the cells chosen so far in this decision
  (the cell itself and the 5x5 around it), with learned weights that start at zero.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from catmip_env.constants import OBS_ONE
from catmip_rl.amat.config import AmatConfig
from catmip_rl.amat.kernels.cell_fields import cell_fields
from catmip_rl.amat.layers import DecoderBlock, as_float
from catmip_rl.amat.model import AMAT, INVALID_LOGIT

__all__ = ["PointerAMAT", "Embedded", "CellContext", "make_model"]

DIST_SCALE = 16.0  # path distances enter the per-cell encoder in units of 16 cells
_PREV = 4  # previous-goal features: offset row, offset column (scaled), stay, present


class CellContext(NamedTuple):
    """What the pointer needs besides the tokens, per robot (B, N, ...)."""

    global_map: torch.Tensor  # (B, N, 5+C, H, W) uint8 (or float)
    pos: torch.Tensor  # (B, N, 2) long: the robot's cell, read from its own-position channel
    dist: torch.Tensor  # (B, N, H, W) int16: path distance on its map, -1 unreachable
    groups: torch.Tensor  # (B, N) long: neighbourhood labels
    hint: torch.Tensor | None = None  # (B, N) long: the hint planner's cell for each robot, -1 none


class Embedded(NamedTuple):
    """Tokens (``embed``) or encoder representations (``encode``) with their cell context."""

    x: torch.Tensor  # (B, N, d)
    cells: CellContext


class _InOrder(NamedTuple):
    """What the decoder reads of each robot, in decision order (:func:`_in_decision_order`)."""

    rep: torch.Tensor  # (B, N, d) encoder output
    actions: torch.Tensor  # (B, N) long: the robots' goals (a new tensor: the decoder may fill it in)
    pos: torch.Tensor  # (B, N, 2) long: the robots' cells
    cls: torch.Tensor  # (B, N, C) class one-hots, in the encoder's dtype
    earlier: torch.Tensor  # (B, N, N) bool: position j comes before k in k's neighbourhood


def make_model(config: AmatConfig | None = None) -> AMAT:
    """The model a config describes: :class:`AMAT` (window goals) or :class:`PointerAMAT` (cell goals)."""
    config = config or AmatConfig()
    return PointerAMAT(config) if config.goals == "cell" else AMAT(config)


class PointerAMAT(AMAT):
    """AMAT whose policy head points at a cell of the map; see the module docstring."""

    def _build_decoder(self) -> None:
        cfg, d, c = self.config, self.config.embed_dim, self.config.cell_channels
        self.prev_enc = nn.Linear(_PREV, d)
        self.dec_class_enc = nn.Linear(cfg.n_classes, d)
        self.dec_ln = nn.LayerNorm(d)
        self.dec_blocks = nn.ModuleList(DecoderBlock(d, cfg.n_heads) for _ in range(cfg.n_blocks))
        # per-cell encoder: the global map's channels + distance + reachable, then dilated residual convs
        self.cell_in = nn.Conv2d(cfg.global_channels + 2 + bool(cfg.hint), c, 3, padding=1)
        self.cell_convs = nn.ModuleList(
            nn.Conv2d(c, c, 3, padding=2 ** max(k - 1, 0), dilation=2 ** max(k - 1, 0))
            for k in range(cfg.cell_layers - 1)
        )
        self.cell_out = nn.Conv2d(c, c + 1, 1)  # features and a per-cell bias
        self.query = nn.Sequential(nn.Linear(d, d), nn.GELU(), nn.LayerNorm(d), nn.Linear(d, c))
        self.claimed = nn.Parameter(torch.zeros(2))  # weights of "chosen by a teammate" and "near one"
        if cfg.hint:  # the bonus of the cell the hint planner proposes (the input channel learns the rest)
            self.hint_bias = nn.Parameter(torch.zeros(1))

    def _activated_layers(self) -> set[nn.Module]:
        return {
            self.global_conv,
            self.local_conv1,
            self.local_conv2,
            self.obs_fc1,
            self.obs_fc2,
            self.class_enc,
            self.value_head[0],
            self.prev_enc,
            self.dec_class_enc,
            self.query[0],
            self.cell_in,
            *self.cell_convs,
        }

    # -- embedder and encoder ---------------------------------------------------------------------
    def embed(self, obs: dict[str, torch.Tensor]) -> Embedded:
        """AMAT's tokens and the cell context; ``obs["neighbourhood"]`` (B, N) if given."""
        gmap = obs["global_map"]
        raw = gmap.cpu().numpy() if gmap.dtype == torch.uint8 else _to_uint8(gmap)
        pos, dist = cell_fields(raw)
        groups = obs.get("neighbourhood")
        if groups is None:
            groups = torch.zeros(gmap.shape[:2], dtype=torch.long, device=gmap.device)
        hint = obs.get("hint")
        if self.config.hint and hint is None:
            raise ValueError(
                f"this AMAT reads the {self.config.hint!r} planner's proposals: its obs needs 'hint' (B, N) "
                "(the cell that planner chose for each robot, -1 none)"
            )
        device = gmap.device
        cells = CellContext(
            gmap,
            torch.from_numpy(pos).to(device),
            torch.from_numpy(dist).to(device),
            groups.long(),
            None if hint is None or not self.config.hint else hint.long(),
        )
        return Embedded(super().embed(obs), cells)

    def encode(
        self, tokens: Embedded, key_padding_mask: torch.Tensor | None = None
    ) -> tuple[Embedded, torch.Tensor]:
        """(Embedded(rep (B, N, d), cells), values (B, N, 1)): attention inside each neighbourhood."""
        allowed = _same_group(tokens.cells.groups)
        if key_padding_mask is not None:
            allowed = allowed & (~key_padding_mask)[:, None, None, :]
        x = self.enc_ln(tokens.x)
        for block in self.enc_blocks:
            x = block(x, allowed)
        return Embedded(x, tokens.cells), self.value_head(x)

    # -- the pointer --------------------------------------------------------------------------------
    def cell_features(self, cells: CellContext, rows: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-cell features (K, c + 1, H, W) (the last channel: a bias) and the narrowed mask
        (K, H * W) bool of the robots at flat indices ``rows`` into B * N."""
        gmap = cells.global_map.flatten(0, 1)[rows]  # (K, 5+C, H, W)
        dist = cells.dist.flatten(0, 1)[rows]  # (K, H, W)
        pos = cells.pos.flatten(0, 1)[rows]  # (K, 2)
        reach = dist >= 0
        x = as_float(gmap)
        dist_in = torch.where(reach, dist.to(x.dtype) / DIST_SCALE, torch.zeros((), dtype=x.dtype))
        x = torch.cat([x, dist_in[:, None], reach[:, None].to(x.dtype)], 1)  # (K, 7+C, H, W)
        if cells.hint is not None:  # the proposed cell, one channel more (none where the hint is -1)
            hint = cells.hint.flatten()[rows]  # (K,)
            proposed = F.one_hot(hint.clamp(min=0), dist[0].numel()) * (hint >= 0)[:, None]  # (K, H * W)
            proposed = proposed.view_as(dist).to(x.dtype)  # (K, H, W)
            x = torch.cat([x, proposed[:, None]], 1)
        # channels-last: oneDNN's convolutions ran 1.7x faster so (fp32, forward + backward, one thread)
        x = x.contiguous(memory_format=torch.channels_last)
        f = F.gelu(self.cell_in(x))
        for conv in self.cell_convs:
            f = f + F.gelu(conv(f))
        f = self.cell_out(f)  # (K, c + 1, H, W)
        if cells.hint is not None:
            c, bonus = f.shape[1] - 1, self.hint_bias.to(f.dtype) * proposed[:, None].to(f.dtype)
            f = torch.cat([f[:, :c], f[:, c:] + bonus], 1)
        if self.config.cell_mask == "known":
            explored = gmap[:, 0] >= (OBS_ONE if gmap.dtype == torch.uint8 else 1.0)
            allowed = (explored & reach).flatten(1)  # (K, H * W); a reachable cell is free on the map
        else:
            allowed = reach.flatten(1).clone()
        w = gmap.shape[-1]
        allowed[torch.arange(len(rows), device=rows.device), pos[:, 0] * w + pos[:, 1]] = True
        return f, allowed

    def point(
        self, h: torch.Tensor, feats: torch.Tensor, allowed: torch.Tensor, claimed: torch.Tensor
    ) -> torch.Tensor:
        """Logits (K, H * W) of decoder outputs h (K, d) over their robots' cells (feats (K, c + 1, H, W)),
        masked by ``allowed`` (K, H * W); ``claimed`` (K, H * W) marks the cells teammates chose already."""
        q = self.query(h)  # (K, c)
        c = q.shape[-1]
        f = feats.flatten(2)  # (K, c + 1, HW)
        logits = torch.einsum("kc,kcx->kx", q, f[:, :c].to(q.dtype)) / math.sqrt(c) + f[:, c]
        hh, ww = feats.shape[-2:]
        near = F.max_pool2d(claimed.view(-1, 1, hh, ww), 5, stride=1, padding=2).flatten(1)
        logits = logits + self.claimed[0] * claimed + self.claimed[1] * near
        return logits.masked_fill(~allowed, INVALID_LOGIT)

    # -- decoder --------------------------------------------------------------------------------------
    def _decode(self, seq: _InOrder, w: int) -> torch.Tensor:
        """Decoder outputs (B, N, d) in decision order, teacher-forced on ``seq.actions`` (each position
        fed the goal of the previous position of its neighbourhood, ``seq.earlier``)."""
        prev = _previous_goal_features(seq.actions, seq.pos, seq.earlier, w)  # (B, N, 4)
        x = self.dec_ln(F.gelu(self.prev_enc(prev.to(seq.rep.dtype))) + F.gelu(self.dec_class_enc(seq.cls)))
        allowed = (seq.earlier | torch.eye(x.shape[1], dtype=torch.bool, device=x.device))[:, None]
        for block in self.dec_blocks:
            x = block(x, seq.rep, allowed)
        return x

    def score(
        self,
        tokens: Embedded,
        actions: torch.Tensor,  # (B, N) long, stored cell actions
        order: torch.Tensor,  # (B, N) long
        agent_class: torch.Tensor,  # (B, N, C)
        select: torch.Tensor,  # (B, N) bool
        action_mask: torch.Tensor | None = None,  # (B, N, H * W)
        key_padding_mask: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Teacher-forced logits (K, H * W) and values (K, 1) of the selected robots, row-major order."""
        rep, values = self.encode(tokens, key_padding_mask)
        logits, rows = self._score_encoded(rep, actions, order, agent_class, select, action_mask)
        return logits, values.flatten(0, 1)[rows]

    def decode_parallel(self, rep, actions, order, agent_class, action_mask=None):
        """Teacher-forced logits (B, N, H * W) of every robot, robot order."""
        sel = torch.ones(actions.shape, dtype=torch.bool, device=actions.device)
        b, n = actions.shape
        logits, _ = self._score_encoded(rep, actions, order, agent_class, sel, action_mask)
        return logits.view(b, n, -1)

    def _score_encoded(self, rep, actions, order, agent_class, select, action_mask):
        """Logits (K, H * W) of the selected robots from encoder output, and their flat rows (K,)."""
        b, n = select.shape
        seq = _in_decision_order(rep, actions, order, agent_class)
        x = self._decode(seq, rep.cells.global_map.shape[-1])
        rows = select.flatten().nonzero()[:, 0]
        pos = torch.empty_like(order).scatter_(1, order, torch.arange(n, device=order.device).expand(b, n))
        rows_o = (pos + torch.arange(b, device=order.device)[:, None] * n).flatten()[rows]
        feats, allowed = self.cell_features(rep.cells, rows)
        if action_mask is not None:
            allowed = allowed & action_mask.flatten(0, 1)[rows].bool()
        claimed = _claimed(seq.actions, seq.earlier, rows_o, feats)
        return self.point(x.flatten(0, 1)[rows_o], feats, allowed, claimed), rows

    @torch.no_grad()
    def decode_autoregressive(
        self,
        rep: Embedded,
        action_mask: torch.Tensor,  # (B, N, H * W)
        order: torch.Tensor,  # (B, N)
        active: torch.Tensor,  # (B, N) bool
        agent_class: torch.Tensor,  # (B, N, C)
        deterministic: bool = False,
        generator: torch.Generator | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Decode the active robots position by position (the decoder rerun on the goals chosen so far:
        a few tokens, cheap beside the cell encoder). Busy robots keep their single allowed goal, log-prob
        0."""
        b, n = active.shape
        mask = action_mask.bool()
        actions = mask.to(torch.uint8).argmax(-1)  # busy robots: their keep action
        log_probs = rep.x.new_zeros(b, n)
        n_active = active.sum(1)
        steps = int(n_active.max()) if b else 0
        if steps == 0:
            return actions, log_probs
        seq, w = _in_decision_order(rep, actions, order, agent_class), rep.cells.global_map.shape[-1]
        chosen_o = seq.actions  # (B, N) decision order, filled in position by position
        flat_o = order + torch.arange(b, device=order.device)[:, None] * n  # robot-order flat index
        for k in range(steps):
            worlds = (n_active > k).nonzero()[:, 0]  # worlds whose k-th position is an active robot
            x = self._decode(seq, w)[worlds, k]  # (K, d)
            rows = flat_o[worlds, k]
            feats, allowed = self.cell_features(rep.cells, rows)
            allowed = allowed & mask.flatten(0, 1)[rows]
            rows_o = worlds * n + k
            claimed = _claimed(chosen_o, seq.earlier, rows_o, feats)
            logits = self.point(x, feats, allowed, claimed)
            logp_all = torch.log_softmax(logits.float(), -1)
            if deterministic:
                a = logits.argmax(-1)
            else:
                a = torch.multinomial(logp_all.exp(), 1, generator=generator)[:, 0]
            chosen_o[worlds, k] = a
            robot = order[worlds, k]
            actions[worlds, robot] = a
            log_probs[worlds, robot] = logp_all.gather(1, a[:, None])[:, 0].to(log_probs.dtype)
        return actions, log_probs

    def forward(self, obs: dict[str, torch.Tensor], key_padding_mask: torch.Tensor | None = None):
        return self.encode(self.embed(obs), key_padding_mask)


def _to_uint8(x: torch.Tensor) -> np.ndarray:
    return (x.detach().float().cpu() * OBS_ONE).round().clamp(0, 255).to(torch.uint8).numpy()


def _same_group(groups: torch.Tensor) -> torch.Tensor:
    """(B, 1, N, N) bool: robots i and j share a neighbourhood."""
    return (groups[:, :, None] == groups[:, None, :])[:, None]


def _in_decision_order(
    rep: Embedded, actions: torch.Tensor, order: torch.Tensor, agent_class: torch.Tensor
) -> _InOrder:
    """The encoder output ``rep``, the robots' ``actions`` (B, N), cells and classes (B, N, C) in decision
    order ``order`` (B, N), and which positions come earlier in each one's neighbourhood."""
    cells, worlds = rep.cells, torch.arange(len(order), device=order.device)[:, None]
    rep_o, actions_o, pos_o, cls_o, groups_o = (  # one index for all: x[b, k] = x[b, order[b, k]]
        x[worlds, order] for x in (rep.x, actions, cells.pos, agent_class.to(rep.x.dtype), cells.groups)
    )
    return _InOrder(rep_o, actions_o, pos_o, cls_o, _earlier_same_group(groups_o))


def _earlier_same_group(groups_o: torch.Tensor) -> torch.Tensor:
    """(B, N, N) bool in decision order: position j comes before k in k's neighbourhood."""
    n = groups_o.shape[1]
    before = torch.ones(n, n, dtype=torch.bool, device=groups_o.device).tril(-1)
    return (groups_o[:, :, None] == groups_o[:, None, :]) & before


def _previous_goal_features(
    actions_o: torch.Tensor, pos_o: torch.Tensor, earlier: torch.Tensor, w: int
) -> torch.Tensor:
    """(B, N, 4): for each position, the goal chosen by the last earlier position of its neighbourhood,
    as its offset from the robot that chose it (scaled by DIST_SCALE), "stay", and "present"."""
    b, n = actions_o.shape
    idx = torch.arange(n, device=actions_o.device)
    last = torch.where(earlier, idx, -1).amax(-1)  # (B, N) previous position, -1 = none
    has = last >= 0
    src = last.clamp_min(0)
    goal = torch.gather(actions_o, 1, src)
    gr, gc = goal // w, goal % w
    p = torch.gather(pos_o, 1, src[..., None].expand(b, n, 2))
    dr, dc = (gr - p[..., 0]).float(), (gc - p[..., 1]).float()
    stay = (dr == 0) & (dc == 0)
    out = torch.stack([dr / DIST_SCALE, dc / DIST_SCALE, stay.float(), torch.ones_like(dr)], -1)
    return torch.where(has[..., None], out, torch.zeros_like(out))


def _claimed(
    actions_o: torch.Tensor, earlier: torch.Tensor, rows_o: torch.Tensor, feats: torch.Tensor
) -> torch.Tensor:
    """(K, H * W) float: 1 on the goals chosen before each of the positions ``rows_o`` (flat decision-order
    indices) by robots of its neighbourhood."""
    hw = feats.shape[-2] * feats.shape[-1]
    n = actions_o.shape[1]
    before = earlier.flatten(0, 1)[rows_o]  # (K, N)
    goals = actions_o.flatten()[(rows_o // n)[:, None] * n + torch.arange(n, device=rows_o.device)]  # (K, N)
    out = torch.zeros(len(rows_o), hw, dtype=feats.dtype, device=feats.device)
    out.scatter_add_(1, goals.clamp(0, hw - 1), before.to(feats.dtype))
    return out.clamp_max(1.0)
