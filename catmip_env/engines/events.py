"""Batched event engine: B worlds, each advancing to its own next decision event (docs/design.md#activation).

>>> eng = EventEngine(PRESETS["train"], num_worlds=64, seed=0)     # goal_mode="window"
>>> ev = eng.reset()                       # t = 0: every robot of every world is active
>>> ev = eng.step(actions)                 # (B, N) goal actions; only active robots' are read
>>> ev.active, ev.rewards, ev.event_ticks  # who decides now, rewards since the last event, ticks run
>>> eng.obs_global, eng.obs_local, eng.masks   # rebuilt only for worlds that were advanced

A decision event is a tick at which at least one robot activates; between events the world runs on
its own (low-level controller, sensing, communication). Worlds whose episode ended are frozen until
``reset(worlds=...)``. Observations are uint8 (``float = value * OBS_SCALE``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from catmip_env.config import EnvConfig
from catmip_env.engines.world import BatchedWorld
from catmip_env.kernels.activation import M_ACTIVE, M_ELAPSED, M_FIELDS, assign_goals, start_activation
from catmip_env.kernels.dynamics import Rules
from catmip_env.kernels.goals import goal_cells
from catmip_env.kernels.macro import action_masks, advance
from catmip_env.kernels.primitive import DirectCall

__all__ = ["EventEngine", "EventResult", "GOAL_MODES", "random_valid_actions"]

GOAL_MODES = ("window", "cell")
INVALID_ACTION_MODES = ("raise", "stay")


def random_valid_actions(masks: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One uniformly random allowed action per robot for masks (..., A) (a random floor, test input)."""
    return np.argmax(rng.random(masks.shape) * masks, axis=-1)


class EventResult(NamedTuple):
    """What a reset or an event step returns. Arrays are the engine's buffers: copy to keep them."""

    active: np.ndarray  # (B, N) bool robots that must choose a goal now
    rewards: np.ndarray  # (B, N) float64 primitive rewards collected since the previous event
    event_ticks: np.ndarray  # (B,) int64 ticks since the previous event (0 at reset)
    terminated: np.ndarray  # (B,) bool the mission succeeded during this step
    truncated: np.ndarray  # (B,) bool the horizon was reached during this step
    ma_rewards: np.ndarray  # (B, N) float64 gamma-discounted reward since each robot's last activation
    ma_ticks: np.ndarray  # (B, N) int64 ticks since each robot's last activation


class EventEngine:
    """Macro-action layer over a :class:`BatchedWorld`: goals, controller, activation, masks.

    ``goal_mode="window"``: action ``a`` in ``[0, D*D)`` is the goal offset
    ``(a // D - D//2, a % D - D//2)`` from the robot (row-major; the centre means stay here).
    ``goal_mode="cell"``: action ``r * W + c`` is the goal cell ``(r, c)`` (for planners).
    ``invalid_action="raise"`` (the default: the trainer's policies are masked, so an invalid action
    is a bug) rejects masked or out-of-range actions of active robots with a ``ValueError``;
    ``"stay"`` replaces them with the robot's own cell and flags them in ``invalid`` (B, N) for the
    last ``step``. ``gamma`` discounts ``ma_rewards`` per elapsed tick.
    """

    def __init__(
        self,
        cfg: EnvConfig,
        num_worlds: int = 1,
        seed: int | None = None,
        goal_mode: str = "window",
        invalid_action: str = "raise",
        gamma: float = 1.0,
        threads: int = 1,
    ) -> None:
        if goal_mode not in GOAL_MODES:
            raise ValueError(f"unknown goal_mode {goal_mode!r}; choose one of {list(GOAL_MODES)}")
        if invalid_action not in INVALID_ACTION_MODES:
            raise ValueError(
                f"unknown invalid_action {invalid_action!r}; choose one of {list(INVALID_ACTION_MODES)}"
            )
        if not 0.0 < gamma <= 1.0:
            raise ValueError(f"gamma must be in (0, 1], got {gamma!r}")
        self.world = BatchedWorld(cfg, num_worlds, seed, threads)
        self.cfg = cfg
        self.goal_mode = goal_mode
        self.invalid_action = invalid_action
        self.gamma = float(gamma)
        b, n, (h, w) = self.world.num_worlds, cfg.num_robots, self.world.shape
        self.num_worlds, self.num_robots, self.shape = b, n, (h, w)
        self.num_actions = cfg.window**2 if goal_mode == "window" else h * w
        self.stay_action = (cfg.window**2) // 2 if goal_mode == "window" else -1
        self.mstate = np.zeros((b, n, M_FIELDS), np.int64)
        # at its compiled entry: each chunk's arguments are C-contiguous views of the same types
        self._advance = DirectCall(advance)
        self.masks = np.zeros((b, n, self.num_actions), np.int8)
        self.invalid = np.zeros((b, n), np.bool_)  # actions replaced by "stay" at the last step
        self._prim = np.zeros((b, n), np.int64)
        self._tick_rewards = np.zeros((b, n), np.float64)
        self._event_rewards = np.zeros((b, n), np.float64)
        self._ma_rewards = np.zeros((b, n), np.float64)
        self._event_ticks = np.zeros(b, np.int64)
        self._terminated = np.zeros(b, np.bool_)
        self._truncated = np.zeros(b, np.bool_)
        self._goal_cells = np.zeros((b, n, 2), np.int64)
        self._refused = np.zeros((b, n), np.bool_)  # scratch of _set_goals
        self.rules = Rules.of(cfg, self.gamma)

    # -- views of the world --------------------------------------------------------------------
    @property
    def state(self):
        return self.world.state

    @property
    def obs_global(self) -> np.ndarray:
        return self.world.obs_global

    @property
    def obs_local(self) -> np.ndarray:
        return self.world.obs_local

    @property
    def active(self) -> np.ndarray:
        """(B, N) bool: robots that decide at the current event."""
        return self.mstate[..., M_ACTIVE] != 0

    def seed(self, seed: int | None) -> None:
        self.world.seed(seed)

    # -- API -----------------------------------------------------------------------------------
    def reset(
        self,
        worlds: np.ndarray | None = None,
        episode_indices: np.ndarray | None = None,
        seed: int | None = None,
    ) -> EventResult:
        """New episodes in ``worlds`` (default all); each starts with a joint decision at t = 0.

        Rewards earned at reset (the target in view at t = 0) are reported with the first step.
        """
        idx = self.world.reset(worlds, episode_indices, seed)
        mask = np.zeros(self.num_worlds, np.bool_)
        mask[idx] = True
        st = self.state
        start_activation(mask, st.target, st.belief, self.mstate)
        st.goal[idx] = -1
        self._event_rewards[idx] = 0.0
        self._ma_rewards[idx] = 0.0
        self._event_ticks[idx] = 0
        self._terminated[idx] = False
        self._truncated[idx] = False
        self.invalid[idx] = False
        self._masks(mask)
        return self._result()

    def step(self, actions: np.ndarray, max_ticks: int | None = None) -> EventResult:
        """Apply the active robots' goal actions (B, N) and run every live world to its next event.

        Entries of busy robots and of finished worlds are ignored. With ``max_ticks`` a world also
        pauses after that many ticks without an event (no robot is active then; the next call just
        continues it) — for tick-by-tick rendering. Rewards and ticks count from the previous call.
        """
        if max_ticks is not None and (not isinstance(max_ticks, (int, np.integer)) or max_ticks < 1):
            raise ValueError(f"max_ticks must be None or an int >= 1, got {max_ticks!r}")
        st = self.state
        live = ~st.done
        self._set_goals(np.asarray(actions), live)
        limit = 0 if max_ticks is None else int(max_ticks)

        def step_chunk(w: slice) -> None:  # the worlds of one thread (threads=): goals, ticks, observations
            assign_goals(
                live[w],
                self._goal_cells[w],
                st.goal[w],
                self.mstate[w],
                self._ma_rewards[w],
                st.comp[w],
                st.heard_goal[w],
            )
            self._advance(  # at its compiled entry: numba's type dispatch of the state takes ~5 us a call
                live[w],
                st.kernel_chunk(w),
                self.rules,
                limit,
                self.mstate[w],
                self._prim[w],
                self._tick_rewards[w],
                self._event_rewards[w],
                self._ma_rewards[w],
                self._event_ticks[w],
                self._terminated[w],
                self._truncated[w],
            )
            self.world.observe_chunk(live, w)
            self._masks_chunk(live, w)

        self.world.chunks.run(step_chunk)
        return self._result()

    def refresh(self, worlds: np.ndarray | None = None) -> None:
        """Rebuild observations and masks of ``worlds`` (default all) after editing ``state`` by hand."""
        mask = np.zeros(self.num_worlds, np.bool_)
        mask[self.world.world_indices(worlds)] = True
        self.world.observe(mask)
        self._masks(mask)

    # -- helpers -------------------------------------------------------------------------------
    def _result(self) -> EventResult:
        return EventResult(
            self.active,
            self._event_rewards,
            self._event_ticks,
            self._terminated,
            self._truncated,
            self._ma_rewards,
            self.mstate[..., M_ELAPSED],
        )

    def _masks(self, worlds: np.ndarray) -> None:
        self.world.chunks.run(lambda w: self._masks_chunk(worlds, w), worlds)

    def _masks_chunk(self, worlds: np.ndarray, w: slice) -> None:
        st = self.state
        action_masks(
            worlds[w],
            self.goal_mode == "cell",
            self.cfg.window,
            st.belief[w],
            st.pos[w],
            st.comp[w],
            st.goal[w],
            self.mstate[w],
            self.masks[w],
        )

    def action_to_cell(self, b: int, i: int, action: int) -> tuple[int, int]:
        """Goal cell of robot i of world b for ``action`` (no validity check)."""
        if self.goal_mode == "cell":
            return divmod(int(action), self.shape[1])
        d = self.cfg.window
        r, c = self.state.pos[b, i]
        return int(r + action // d - d // 2), int(c + action % d - d // 2)

    def _set_goals(self, actions: np.ndarray, live: np.ndarray) -> None:
        b_, n = self.num_worlds, self.num_robots
        if actions.shape != (b_, n):
            raise ValueError(
                f"actions must have shape (num_worlds, num_robots) = ({b_}, {n}), got {actions.shape}"
            )
        if not np.issubdtype(actions.dtype, np.integer):
            raise ValueError(f"goal actions must be integers, got dtype {actions.dtype}")
        decides = self.active & live[:, None]
        refused = goal_cells(
            actions.astype(np.int64),
            decides,
            self.masks,
            self.goal_mode == "cell",
            self.shape[1],
            self.cfg.window,
            self.stay_action,
            self.state.pos,
            self._goal_cells,
            self._refused,
        )
        if refused and self.invalid_action == "raise":
            b, i = (int(x) for x in np.argwhere(self._refused)[0])
            v = int(actions[b, i])
            if 0 <= v < self.num_actions:
                what = f"masked: its goal cell {self.action_to_cell(b, i, v)} is not allowed by the mask"
            else:
                what = f"out of range: {self.goal_mode} actions are 0..{self.num_actions - 1}"
            raise ValueError(
                f"action {v} of robot_{i} (world {b}) is {what} "
                f"(invalid_action='stay' would replace it with 'stay here')"
            )
        self.invalid[:] = self._refused
