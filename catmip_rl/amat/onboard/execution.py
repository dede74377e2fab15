"""Distributed execution (docs/design.md#distributed-execution): :class:`AmatExecutor` runs AMAT over a
batch of worlds as the robots would, with message accounting (its decisions, one per communication
neighbourhood, are ``catmip_rl.amat.onboard.neighbourhoods``'); :class:`CellGoalExecutor` does the same
for a cell-goal AMAT.
"""

from __future__ import annotations

import numpy as np
import torch

from catmip_env.engines.events import EventEngine
from catmip_env.kernels.state import WorldState
from catmip_env.planners.proposals import Proposals
from catmip_env.play import MESSAGE_COLUMNS
from catmip_rl.amat.inputs import clean_occupancy, macro_observation
from catmip_rl.amat.model import AMAT, decision_order
from catmip_rl.amat.onboard.fast_amat import FastAmat
from catmip_rl.amat.onboard.neighbourhoods import (
    GOAL_BYTES,
    active_neighbourhoods,
    decide_neighbourhoods,
    decide_neighbourhoods_fast,
    message_bytes,
)

__all__ = ["AmatExecutor", "CellGoalExecutor"]


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
                self.model,
                engine.obs_global,
                engine.obs_local,
                st.cls,
                masks,
                active,
                st.comp,
                engine.stay_action,
                self.deterministic,
                self.generator,
            )
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

    def __init__(
        self,
        model: AMAT,
        deterministic: bool = True,
        generator: torch.Generator | None = None,
        loop_guard: bool = False,
        clean_occupancy: bool = False,
    ) -> None:
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
                rep,
                torch.from_numpy(masks_w),
                decision_order(act),
                act,
                obs["agent_class"],
                deterministic=self.deterministic,
                generator=self.generator,
            )
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
