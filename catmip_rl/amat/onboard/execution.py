"""Distributed execution (docs/design.md#distributed-execution): :class:`AmatExecutor` runs AMAT over a
batch of worlds as the robots would, with message accounting; its decisions are
:func:`decide_neighbourhoods` (``decide_by_neighbourhood``: the same on one world's tensors), and the
helpers below do one neighbourhood by hand. In both, every robot embeds its own macro-observation and
sends a d-float token; the coordinator of each neighbourhood (its lowest id) runs encoder + decoder on
the members' tokens only and sends each active member its goal.

>>> token = embed_robot(model, obs, i)                  # on robot i: (d,)
>>> goals = coordinate(model, tokens, classes, masks, active)   # on the coordinator
>>> message_bytes(model.config, map_shape=(20, 20))    # embedding vs raw macro-observation
"""

from __future__ import annotations

import numpy as np
import torch

from catmip_env.events import EventEngine
from catmip_env.kernels.state import WorldState
from catmip_env.planners.proposals import Proposals
from catmip_env.play import MESSAGE_COLUMNS
from catmip_rl.amat.config import AmatConfig
from catmip_rl.amat.inputs import clean_occupancy, macro_observation
from catmip_rl.amat.model import AMAT, decision_order
from catmip_rl.amat.onboard.fast_amat import FastAmat

__all__ = [
    "AmatExecutor",
    "CellGoalExecutor",
    "GOAL_BYTES",
    "embed_robot",
    "coordinate",
    "message_bytes",
    "decide_neighbourhoods",
    "decide_neighbourhoods_fast",
    "active_neighbourhoods",
    "decide_by_neighbourhood",
]

GOAL_BYTES = 2
"""A goal message: the window index (D^2 <= 65,536) as an unsigned 16-bit integer."""


@torch.no_grad()
def embed_robot(model: AMAT, obs: dict[str, torch.Tensor], i: int) -> torch.Tensor:
    """Robot i's token (d,) from a team observation dict with (N, ...) entries (no batch dim)."""
    one = {k: v[i : i + 1][None] for k, v in obs.items()}  # (1, 1, ...)
    return model.embed(one)[0, 0]


@torch.no_grad()
def coordinate(
    model: AMAT,
    tokens: torch.Tensor,  # (M, d) members' tokens, ascending robot id
    agent_class: torch.Tensor,  # (M, C)
    action_mask: torch.Tensor,  # (M, A)
    active: torch.Tensor,  # (M,) bool
    deterministic: bool = True,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Encoder + decoder over one neighbourhood's tokens: (actions (M,), log_probs (M,))."""
    rep, _ = model.encode(tokens[None])
    order = decision_order(active[None])
    a, lp = model.decode_autoregressive(
        rep, action_mask[None], order, active[None], agent_class[None], deterministic=deterministic
    )
    return a[0], lp[0]


@torch.no_grad()
def decide_by_neighbourhood(
    model: AMAT,
    obs: dict[str, torch.Tensor],  # (N, ...) entries of one world
    action_mask: torch.Tensor,  # (N, A)
    active: torch.Tensor,  # (N,) bool
    neighbourhood: torch.Tensor,  # (N,) long labels
    deterministic: bool = True,
) -> torch.Tensor:
    """Goals (N,) of one world decided neighbourhood by neighbourhood (busy robots: their first valid
    action): :func:`decide_neighbourhoods` (what :class:`AmatExecutor` runs) on a batch of one world."""
    labels = neighbourhood.numpy()
    lowest = np.array([np.flatnonzero(labels == label)[0] for label in labels], np.int64)
    actions, _, _ = decide_neighbourhoods(
        model,
        obs["global_map"].numpy()[None],
        obs["local_map"].numpy()[None],
        obs["agent_class"].argmax(-1).numpy()[None],
        action_mask.numpy()[None],
        active.numpy().astype(np.bool_)[None],
        lowest[None],
        stay_action=action_mask.shape[-1] // 2,  # the window's centre
        deterministic=deterministic,
    )
    return torch.from_numpy(actions[0])


def message_bytes(config: AmatConfig, map_shape: tuple[int, int], float_bytes: int = 4) -> dict[str, int]:
    """Bytes one robot sends per decision: its embedding vs its raw macro-observation (float32 maps
    + class one-hot), and the raw maps stored as uint8."""
    h, w = map_shape
    l2 = config.local_size**2
    raw_values = config.global_channels * h * w + config.local_channels * l2
    return {
        "embedding": config.embed_dim * float_bytes,
        "raw_float32": (raw_values + config.n_classes) * float_bytes,
        "raw_uint8": raw_values + config.n_classes,
    }


@torch.no_grad()
def decide_neighbourhoods(
    model: AMAT,
    global_map: np.ndarray,  # (B, N, 5+C, H, W) uint8 macro-observations
    local_map: np.ndarray,  # (B, N, 4+C, L, L) uint8
    cls: np.ndarray,  # (B, N) int class index
    masks: np.ndarray,  # (B, N, A) action masks
    active: np.ndarray,  # (B, N) bool robots that decide now
    comp: np.ndarray,  # (B, N) int neighbourhood label = its lowest robot id
    stay_action: int,
    deterministic: bool = True,
    generator: torch.Generator | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The decisions of every neighbourhood with an active robot, each on its members' tokens only
    (encoder + decoder on one padded row per neighbourhood: other rows' robots are invisible):
    (actions (B, N) int64 (inactive robots: their first valid action), the world of each decided
    neighbourhood (R,), its members (R, N) bool)."""
    b, n = active.shape
    actions = masks.argmax(-1).astype(np.int64)
    if not active.any():
        return actions, np.zeros(0, np.int64), np.zeros((0, n), np.bool_)
    b_of_row, member = active_neighbourhoods(active, comp)
    r = len(b_of_row)
    slot = np.cumsum(member, axis=1) - 1  # position of each member inside its row
    row_idx, robot = np.nonzero(member)
    pos = slot[row_idx, robot]
    world = b_of_row[row_idx]
    # every member embeds its own macro-observation (robots of other neighbourhoods need not)
    c = model.config.n_classes
    obs = macro_observation(
        global_map[world, robot][None], local_map[world, robot][None], cls[world, robot][None], c
    )
    tokens = model.embed(obs)[0]  # (K, d)
    tok = tokens.new_zeros(r, n, tokens.shape[-1])
    tok[row_idx, pos] = tokens
    padding = torch.ones(r, n, dtype=torch.bool)
    padding[row_idx, pos] = False
    act_rows = torch.zeros(r, n, dtype=torch.bool)
    act_rows[row_idx, pos] = torch.from_numpy(active[world, robot])
    mask_rows = torch.zeros(r, n, masks.shape[-1], dtype=torch.bool)
    mask_rows[:, :, stay_action] = True  # padding slots: any single valid entry
    mask_rows[row_idx, pos] = torch.from_numpy(masks[world, robot].astype(np.bool_))
    cls_rows = torch.zeros(r, n, c)
    cls_rows[row_idx, pos] = obs["agent_class"][0]
    rep, _ = model.encode(tok, key_padding_mask=padding)
    order = decision_order(act_rows, padding)
    a, _ = model.decode_autoregressive(
        rep, mask_rows, order, act_rows, cls_rows, deterministic=deterministic,
        generator=generator,
    )  # fmt: skip
    chosen = a[row_idx, pos].numpy()
    is_active = act_rows[row_idx, pos].numpy()
    actions[world[is_active], robot[is_active]] = chosen[is_active]
    return actions, b_of_row, member


def active_neighbourhoods(active: np.ndarray, comp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The neighbourhoods that decide at an event: one row per (world, component label = its lowest
    robot id) with an active member, in world then label order: (world of each row (R,), its members
    (R, N) bool, ascending id)."""
    b, n = active.shape
    bb, ii = np.nonzero(active)
    has_active = np.zeros((b, n), np.bool_)
    has_active[bb, comp[bb, ii]] = True
    b_of_row, label = np.nonzero(has_active)
    return b_of_row, comp[b_of_row] == label[:, None]


def decide_neighbourhoods_fast(
    fast: FastAmat,
    global_map: np.ndarray,
    local_map: np.ndarray,
    cls: np.ndarray,
    masks: np.ndarray,
    active: np.ndarray,
    comp: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`decide_neighbourhoods` with argmax actions, each neighbourhood decided at batch 1 by
    ``fast`` (the batch-1 runtime, as a coordinator runs it): the same actions and rows in the same
    order, without padding every neighbourhood to the team's size."""
    actions = masks.argmax(-1).astype(np.int64)
    b_of_row, member = active_neighbourhoods(active, comp)
    for w, m in zip(b_of_row, member):
        ids, act = np.flatnonzero(m), active[w][m]
        chosen, _, _ = fast.decide(
            global_map[w][m], local_map[w][m], cls[w][m], masks[w][m].astype(np.bool_), act
        )
        actions[w, ids[act]] = chosen[act]
    return actions, b_of_row, member


class AmatExecutor:
    """Distributed execution of an AMAT policy over a batch of worlds of an :class:`EventEngine`
    (window goal mode), with message accounting.

    At an event, every robot of a live world embeds its own macro-observation (one batched call). For
    every neighbourhood with an active robot, its members' tokens (ascending id) form one row of a
    padded batch; encoder and decoder run on each row with the other rows' robots invisible (padding
    masked). With full communication there is one neighbourhood per world and the decision equals the
    centralised one exactly.

    Argmax decisions of a model on the CPU run on the batch-1 runtime (``FastAmat``, a snapshot of the
    weights taken here), one neighbourhood at a time as a coordinator would: the same actions, 1.3-4x
    faster per event than the padded torch batch (``benchmarks/bench_executor.py``: 64 Task-2 / 32
    Task-3 worlds, one thread). ``fast=False``, sampled actions and a GPU model use the torch batch.
    The snapshot is not updated: build a new executor after the model changes.
    """

    def __init__(
        self,
        model: AMAT,
        deterministic: bool = True,
        generator: torch.Generator | None = None,
        loop_guard: bool = False,
        fast: bool = True,
    ):
        self.model = model.eval()
        on_cpu = all(p.device.type == "cpu" for p in model.parameters())
        self.fast = FastAmat.from_model(model) if fast and deterministic and on_cpu else None
        self.deterministic = deterministic
        self.generator = generator
        self.loop_guard = loop_guard
        self.messages = self.bytes_embedding = self.bytes_raw = None
        self._last_action = self._last_pose = None

    def sampled(self, seed: int) -> AmatExecutor:
        """The same model and play options with sampled actions, drawn from a generator seeded by ``seed``."""
        return type(self)(self.model, False, torch.Generator().manual_seed(seed), **self._play_options())

    def _play_options(self) -> dict[str, bool]:
        """How this executor plays, as its constructor takes it (what :meth:`sampled` keeps)."""
        return {"loop_guard": self.loop_guard}

    def episode_columns(self) -> dict[str, np.ndarray]:
        """The decision traffic of each episode since :meth:`start_episodes` (catmip_env.play.Policy)."""
        return dict(zip(MESSAGE_COLUMNS, (self.messages, self.bytes_embedding, self.bytes_raw), strict=True))

    def start_episodes(self, num_worlds: int, num_robots: int = 0) -> None:
        """Zero the message counters (and the loop guard's memory) for a new batch of episodes."""
        self.messages = np.zeros(num_worlds, np.int64)
        self.bytes_embedding = np.zeros(num_worlds, np.int64)
        self.bytes_raw = np.zeros(num_worlds, np.int64)
        self._last_action = np.full((num_worlds, num_robots), -1, np.int64)
        self._last_pose = np.zeros((num_worlds, num_robots, 3), np.int64)

    def _guarded_masks(self, engine: EventEngine, active: np.ndarray) -> np.ndarray:
        """The loop guard: a robot whose last macro-action left it where it was (same cell, same
        heading) may not choose that goal again, unless it is its only valid one. Under evaluation
        activation (0, 0) an argmax policy that stalls would otherwise decide again at once on an almost
        unchanged observation and repeat itself until something else moves."""
        st = engine.state
        pose = np.concatenate([st.pos, st.heading[..., None].astype(st.pos.dtype)], -1)
        masks = engine.masks
        stalled = active & (self._last_action >= 0) & (pose == self._last_pose).all(-1)
        if stalled.any():
            masks = masks.copy()
            for b, i in zip(*np.nonzero(stalled)):
                if masks[b, i].sum() > 1:
                    masks[b, i, self._last_action[b, i]] = 0
        self._last_pose[active] = pose[active]
        return masks

    def check_memory(self, engine: EventEngine) -> None:
        """ValueError unless the engine shows remembered teammates exactly when the model reads them."""
        for name in ("teammate_memory", "teammate_heading"):
            if getattr(engine.cfg, name) != getattr(self.model.config, name):
                raise ValueError(
                    f"this AMAT was trained {'with' if getattr(self.model.config, name) else 'without'} "
                    f"{name} in its observation; the engine has {name}={getattr(engine.cfg, name)}"
                )

    @torch.no_grad()
    def act(self, engine: EventEngine) -> np.ndarray:
        """Goal actions (B, N) of the active robots of live worlds (others: anything valid)."""
        if engine.goal_mode != "window" or engine.cfg.window != self.model.config.window:
            raise ValueError(
                f"AMAT with window {self.model.config.window} needs an EventEngine in window mode with "
                f"window {self.model.config.window}, got {engine.goal_mode!r} / {engine.cfg.window}"
            )
        st, active, masks = self._begin_decision(engine)
        if self.fast is not None:
            actions, b_of_row, member = decide_neighbourhoods_fast(
                self.fast, engine.obs_global, engine.obs_local, st.cls, masks, active, st.comp
            )
        else:
            actions, b_of_row, member = decide_neighbourhoods(
                self.model, engine.obs_global, engine.obs_local, st.cls, masks, active, st.comp,
                engine.stay_action, self.deterministic, self.generator,
            )  # fmt: skip
        if not active.any():
            return actions
        self._last_action[active] = actions[active]
        self._count(engine, b_of_row, member, active)
        return actions

    def _begin_decision(self, engine: EventEngine) -> tuple[WorldState, np.ndarray, np.ndarray]:
        """(state, active (B, N): the active robots of live worlds, the masks they choose from: the
        engine's, or the loop guard's), after checking the memory option and sizing the counters."""
        self.check_memory(engine)
        if self.messages is None or self._last_action.shape != (engine.num_worlds, engine.num_robots):
            self.start_episodes(engine.num_worlds, engine.num_robots)
        st = engine.state
        active = engine.active & ~st.done[:, None]
        return st, active, self._guarded_masks(engine, active) if self.loop_guard else engine.masks

    def _count(self, engine: EventEngine, b_of_row: np.ndarray, member: np.ndarray, active: np.ndarray):
        sizes = message_bytes(self.model.config, engine.shape)
        for k, b in enumerate(b_of_row):
            ids = np.flatnonzero(member[k])
            others = ids[1:]  # the coordinator is the lowest id
            n_goals = int(active[b, others].sum())
            self.messages[b] += len(others) + n_goals
            self.bytes_embedding[b] += len(others) * sizes["embedding"] + n_goals * GOAL_BYTES
            self.bytes_raw[b] += len(others) * sizes["raw_float32"] + n_goals * GOAL_BYTES


class CellGoalExecutor(AmatExecutor):
    """Distributed execution of a cell-goal AMAT (``amat.pointer``) over an :class:`EventEngine` in cell
    goal mode, with the same message accounting (a goal message is the cell index, H * W <= 65,536).

    One batched pass over the worlds with an active robot: the model attends and decodes inside each
    neighbourhood only (its ``neighbourhood`` input), which is each neighbourhood deciding on its own.
    ``clean_occupancy``: the active robots read occupancy from their masks
    (:func:`~catmip_rl.amat.inputs.clean_occupancy`): under SLAM noise, the map the planners choose on.
    A model with a hint (``AmatConfig.hint``) reads that planner's proposal for each active robot
    (:class:`~catmip_env.planners.proposals.Proposals`, as the collector and the TorchRL env give it).
    """

    def __init__(self, model: AMAT, deterministic: bool = True, generator: torch.Generator | None = None,
                 loop_guard: bool = False, clean_occupancy: bool = False) -> None:  # fmt: skip
        super().__init__(model, deterministic, generator, loop_guard, fast=False)
        self.clean_occupancy = clean_occupancy
        self.proposals = Proposals(model.config.hint)

    def _play_options(self) -> dict[str, bool]:
        return super()._play_options() | {"clean_occupancy": self.clean_occupancy}

    @torch.no_grad()
    def act(self, engine: EventEngine) -> np.ndarray:
        """Cell goal actions (B, N) of the active robots of live worlds (others: their current goal)."""
        if engine.goal_mode != "cell":
            raise ValueError(
                f"a cell-goal AMAT needs an EventEngine with goal_mode='cell', got {engine.goal_mode!r}"
            )
        st, active, masks = self._begin_decision(engine)
        actions = masks.argmax(-1).astype(np.int64)
        if not active.any():
            return actions
        w = np.flatnonzero(active.any(1))
        global_map, local_map = engine.obs_global[w], engine.obs_local[w]
        if self.clean_occupancy:  # the engine's masks (not the guard's): the clean belief's free cells
            global_map, local_map = clean_occupancy(
                global_map, local_map, engine.masks[w], st.pos[w], st.comp[w], active[w]
            )
        hint = self.proposals(engine)[w]  # the active robots' proposals (-1 elsewhere, and without a hint)
        obs = macro_observation(
            global_map, local_map, st.cls[w], self.model.config.n_classes, st.comp[w], hint=hint
        )
        act = torch.from_numpy(active[w])
        rep, _ = self.model.encode(self.model.embed(obs))

        def decide(masks_w: np.ndarray) -> np.ndarray:
            chosen, _ = self.model.decode_autoregressive(
                rep, torch.from_numpy(masks_w), decision_order(act), act, obs["agent_class"],
                deterministic=self.deterministic, generator=self.generator,
            )  # fmt: skip
            return chosen.numpy()

        masks_w = masks[w]
        chosen = decide(masks_w)
        if self.loop_guard:
            # the guard can take away the one cell the model's own mask (cell_mask) left a robot: such a
            # robot gets its unguarded mask back and its neighbourhood decides again
            lost = active[w] & ~np.take_along_axis(masks_w, chosen[..., None], -1)[..., 0].astype(bool)
            if lost.any():
                chosen = decide(np.where(lost[..., None], engine.masks[w], masks_w))
        actions[w] = chosen
        self._last_action[active] = actions[active]
        self._count(engine, *active_neighbourhoods(active, st.comp), active)
        return actions
