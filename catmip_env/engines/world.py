"""The batched world (:class:`BatchedWorld`): B independent worlds as one struct of arrays, stepped one
tick per call.

>>> eng = BatchedWorld(PRESETS["task2"], num_worlds=64, seed=0)
>>> eng.reset()                                   # every world draws its episode's map
>>> res = eng.step(actions)                       # actions: (B, N) ints in [0, 4)
>>> res.rewards, res.terminated, res.truncated    # (B, N), (B,), (B,)
>>> eng.obs_global, eng.obs_local                 # uint8 macro-observations, float = x * OBS_SCALE
>>> eng.reset(worlds=eng.done)                    # start the next episodes of finished worlds

Episodes are numbered: world resets take consecutive episode indices (or explicit ones), and
episode ``k`` of seed ``s`` always has the same map, team and spawn poses (and communication range,
when ``EnvConfig.comm_sigma_choices`` offers several), drawn from ``SeedSequence(s, spawn_key=(k,))``;
its dynamics (communication links, SLAM noise) draw from a sibling stream, so a world's trajectory
depends only on ``(s, k)`` and its actions — not on B or on other worlds.

Each world also has a **key** (``world_keys[b]``, a 63-bit int drawn from a third sibling stream of its
episode): what a policy reads of the world's identity (per-world random streams keyed by it reproduce a
map played alone), which names neither the seed nor the episode index.
"""

from __future__ import annotations

import numbers
from typing import Any, NamedTuple

import numpy as np

from catmip_env.ascii_maps import parse_layout
from catmip_env.config import EnvConfig
from catmip_env.constants import (
    CLUE,
    EXPLORED,
    OBS_SCALE,
    OBSTACLE,
    TARGET,
    TARGET_BIT,
    WALL,
    global_channels,
    local_channels,
)
from catmip_env.engines.chunks import WorldChunks
from catmip_env.kernels.comms import estimated_cells
from catmip_env.kernels.dynamics import Rules, perceive_at_reset, tick
from catmip_env.kernels.episodes import load_episodes
from catmip_env.kernels.mapgen import first_block, raise_map_error, target_exclusion_side
from catmip_env.kernels.observe import observe as build_observations
from catmip_env.kernels.primitive import DirectCall, robot_view, tick_and_observe, tick_observe_view
from catmip_env.kernels.rng import seed_state
from catmip_env.kernels.seeding import int_words
from catmip_env.kernels.state import WorldState

__all__ = [
    "BatchedWorld",
    "StepResult",
    "WorldChunks",
    "EPISODE_INDEX_LIMIT",
    "episode_index_array",
    "world_key",
]

TICK_SPLIT_WORK = 150_000
"""A primitive step (one tick) runs on several threads only from this many worlds x robots x cells
(Task 2: 125 worlds, Task 3: 25): below it, waking a second thread costs more than it saves (measured
by ``benchmarks/bench_threads.py`` on a 2-core AVX2 machine: two threads at 0.48x one for 16 Task-2
worlds, 0.99x for 64). A decision event is enough work to split from 16 worlds."""

#: Episode indices are below this: they are stored as int64 (``WorldState.episode``), and the numbering
#: goes on after the largest one used.
EPISODE_INDEX_LIMIT = 2**62


def episode_index_array(indices: Any, what: str = "episode index") -> np.ndarray:
    """(E,) int64 episode indices from a list or array of ints, each in [0, EPISODE_INDEX_LIMIT); else a
    ValueError naming ``what`` and the first bad value (not numpy's OverflowError, nor a silent cast)."""
    array = np.asarray(indices)
    if array.dtype.kind not in "iu":  # numpy turns [0, 2**63] to floats: take the values as given instead
        array = np.asarray(indices, dtype=object)
    values = array.reshape(-1).tolist()  # Python numbers: comparing them cannot overflow

    def ok(v: Any) -> bool:
        return isinstance(v, numbers.Integral) and not isinstance(v, bool) and 0 <= v < EPISODE_INDEX_LIMIT

    bad = next((e for e, v in enumerate(values) if not ok(v)), None)
    if bad is not None:
        raise ValueError(f"{what} must be an int in [0, 2**62), got {values[bad]!r}")
    return np.array(values, np.int64)


class StepResult(NamedTuple):
    """What one batched tick returns. Arrays are the engine's buffers: copy them to keep them."""

    rewards: np.ndarray  # (B, N) float64 reward of each robot on this tick
    terminated: np.ndarray  # (B,) bool mission succeeded on this tick
    truncated: np.ndarray  # (B,) bool horizon reached without success on this tick


class BatchedWorld:
    """B independent worlds of one :class:`EnvConfig`, advanced one primitive tick per call.

    Worlds whose episode is over (``done``) are frozen by :meth:`step` until :meth:`reset` starts
    their next episode. Observations are rebuilt for every stepped or reset world.
    """

    def __init__(
        self, cfg: EnvConfig, num_worlds: int = 1, seed: int | None = None, threads: int = 1
    ) -> None:
        if not isinstance(cfg, EnvConfig):
            raise TypeError(f"cfg must be an EnvConfig, got {type(cfg).__name__}")
        if not isinstance(num_worlds, (int, np.integer)) or num_worlds < 1:
            raise ValueError(f"num_worlds must be an int >= 1, got {num_worlds!r}")
        self.chunks = WorldChunks(int(num_worlds), threads)
        self.cfg = cfg
        self.num_worlds = int(num_worlds)
        self.num_robots = cfg.num_robots
        self.shape = cfg.map_shape
        self.noisy = cfg.slam_noise > 0.0
        self.memory, self.heading = cfg.teammate_memory, cfg.teammate_heading
        self.state = WorldState.allocate(self.num_worlds, self.num_robots, self.shape, self.noisy)
        b, n, (h, w), c = self.num_worlds, self.num_robots, self.shape, cfg.num_classes
        self.obs_global = np.zeros((b, n, global_channels(c), h, w), np.uint8)
        self.obs_local = np.zeros((b, n, local_channels(c), cfg.local_size, cfg.local_size), np.uint8)
        self._rewards = np.zeros((b, n), np.float64)
        self._terminated = np.zeros(b, np.bool_)
        self._truncated = np.zeros(b, np.bool_)
        self._speed_of = np.array([k.ticks_per_action for k in cfg.classes], np.int64)
        self._rescue_of = np.array([k.can_rescue for k in cfg.classes], np.bool_)
        self._comm_of = np.array([0.0 if c is None else float(c) for c in cfg.comm_ranges], np.float64)
        self.rules = Rules.of(cfg)
        self._action_shape = (b, n)
        self._result = StepResult(self._rewards, self._terminated, self._truncated)  # the same buffers
        # a tick on one thread without the teammates' heading estimate: tick and observations in one call
        self._small = self.num_worlds * self.num_robots * self.shape[0] * self.shape[1] < TICK_SPLIT_WORK
        self._one_call = (self._small or self.chunks.threads == 1) and not self.heading
        self._tick_observe = DirectCall(tick_and_observe)
        self._tick_observe_view = DirectCall(tick_observe_view)
        self._robot_view = DirectCall(robot_view)
        self._view_shapes = (self.obs_global.shape[1:], self.obs_local.shape[1:], (n, c), (n, 4), (n, 5))
        self._info = np.zeros((n, 5), np.int64)  # step_viewed's info numbers
        self._kernel_args = (self.state.kernel, self.rules, self._rewards, self._terminated, self._truncated,
                             self.noisy, self.memory, self.obs_global, self.obs_local, OBS_SCALE)  # fmt: skip
        self.world_keys = np.zeros(self.num_worlds, np.int64)  # each world's key (world_key)
        self._episode_args = episode_rules(cfg, self._speed_of, self._rescue_of, self._comm_of)
        self.seed(seed)

    # -- seeding and reset ---------------------------------------------------------------------
    def seed(self, seed: int | None) -> None:
        """Set the base seed and restart episode numbering at 0 (``None`` draws OS entropy)."""
        if seed is None:
            seed = int(np.random.SeedSequence().entropy % (2**63))
        if not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"seed must be a non-negative int or None, got {seed!r}")
        self.base_seed = int(seed)
        self._seed_words = int_words(self.base_seed)  # as the reset's kernel takes it
        self.next_episode = 0

    def reset(
        self,
        worlds: np.ndarray | None = None,
        episode_indices: np.ndarray | None = None,
        seed: int | None = None,
    ) -> np.ndarray:
        """Start new episodes in ``worlds`` (bool mask (B,) or indices; default all).

        ``seed`` (optional) re-seeds first (episode numbering restarts at 0). Episode indices default
        to the next unused ones, in world order. Returns the indices of the reset worlds.
        """
        if seed is not None:
            self.seed(seed)
        idx = self.world_indices(worlds)
        if episode_indices is None:
            episode_indices = np.arange(self.next_episode, self.next_episode + len(idx))
        episode_indices = episode_index_array(episode_indices)
        if len(episode_indices) != len(idx):
            raise ValueError(f"got {len(episode_indices)} episode indices for {len(idx)} worlds being reset")
        if len(episode_indices):
            self.next_episode = max(self.next_episode, int(episode_indices.max()) + 1)
        st = self.state
        mask = np.zeros(self.num_worlds, np.bool_)
        mask[idx] = True
        st.pending_reward[idx] = 0.0
        codes = np.zeros(len(idx), np.int64)

        def reset_chunk(w: slice) -> None:  # each thread's worlds: maps, streams, perception, observations
            load_episodes(idx, episode_indices, w.start, w.stop, self._seed_words, st.kernel, self.world_keys,
                          codes, *self._episode_args)  # fmt: skip
            if not codes.any():
                perceive_at_reset(mask[w], st.kernel_chunk(w), self.rules)
                self.observe_chunk(mask, w)

        self.chunks.run(reset_chunk, mask)
        if codes.any():
            raise_map_error(self.cfg, int(codes[np.flatnonzero(codes)[0]]))
        return idx

    def episode_streams(self, episode: int) -> tuple[np.random.Generator, np.uint64]:
        """(map generator, dynamics kernel state) of episode ``episode`` under the base seed."""
        seq = np.random.SeedSequence(self.base_seed, spawn_key=(episode,))
        map_seq, dyn_seq = seq.spawn(2)
        return np.random.default_rng(map_seq), seed_state(dyn_seq)

    def world_indices(self, worlds: np.ndarray | None) -> np.ndarray:
        """Indices of the worlds named by a bool mask (B,) or an index list (None: all); checked."""
        if worlds is None:
            return np.arange(self.num_worlds)
        w = np.asarray(worlds)
        if w.dtype == np.bool_:
            if w.shape != (self.num_worlds,):
                raise ValueError(f"world mask must have shape ({self.num_worlds},), got {w.shape}")
            return np.flatnonzero(w)
        w = w.astype(np.int64).reshape(-1)
        if len(w) and (w.min() < 0 or w.max() >= self.num_worlds):
            raise ValueError(f"world indices must be in [0, {self.num_worlds}), got {w.tolist()}")
        return w

    # -- stepping ------------------------------------------------------------------------------
    def step(self, actions: np.ndarray) -> StepResult:
        """Advance every world that is not done by one tick with primitive ``actions`` (B, N).

        Done worlds are left as they are (zero reward, flags false) until reset.
        """
        a = self._kernel_actions(actions)
        live = ~self.state.done
        if self._one_call:  # too little work a tick to be worth a second thread: one kernel call
            self._raise_out_of_range(a, self._tick_observe(live, a, *self._kernel_args[:-1]))
            return self._result
        if a.size and (a.min() < 0 or a.max() > 3):  # checked before any chunk moves
            self._raise_out_of_range(a, int(np.flatnonzero((a < 0) | (a > 3))[0]))
        if not self.heading:  # each thread's chunk in one kernel call
            _, rules, r, te, tr, noisy, memory, g, l = self._kernel_args[:-1]
            chunk_state, call = self.state.kernel_chunk, self._tick_observe
            self.chunks.run(lambda w: call(live[w], a[w], chunk_state(w), rules, r[w], te[w], tr[w], noisy,
                                           memory, g[w], l[w]))  # fmt: skip
            return self._result

        def step_chunk(w: slice) -> None:
            k = self.state.kernel_chunk(w)
            tick(live[w], a[w], k, self.rules, self._rewards[w], self._terminated[w], self._truncated[w])
            self.observe_chunk(live, w)

        if self._small:
            step_chunk(slice(0, self.num_worlds))
        else:
            self.chunks.run(step_chunk)
        return self._result

    def step_viewed(self, actions: np.ndarray) -> tuple[StepResult, tuple[np.ndarray, ...]]:
        """:meth:`step`, and world 0's :meth:`view` built in the same kernel call where :meth:`step`
        takes one (the PettingZoo env's primitive step); the view's info numbers are a buffer of the
        world's here, rewritten at the next step."""
        a = self._kernel_actions(actions)
        if not self._one_call:
            return self.step(a), self.view(0)
        view = self._new_view(self._info)
        call = self._tick_observe_view.entry or self._tick_observe_view  # in a hot loop: the entry itself
        self._raise_out_of_range(a, call(*self._kernel_args, 0, a, *view))
        return self._result, view

    def view(self, b: int) -> tuple[np.ndarray, ...]:
        """What the primitive-level env shows of world ``b``, in new arrays: every robot's maps as float32
        (``value * OBS_SCALE``), its class and heading one-hots, and its info numbers (N, 5) int64: class,
        neighbourhood, can act now, knows the target, tick (:func:`~.kernels.primitive.robot_view`)."""
        view = self._new_view()
        self._robot_view(b, self.obs_global, self.obs_local, self.state.kernel, OBS_SCALE, *view)
        return view

    def _new_view(self, info: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
        """New float arrays for a view, and ``info`` for its numbers (None: a new array too)."""
        (g, l, c, h, i), f32 = self._view_shapes, np.float32
        info = np.empty(i, np.int64) if info is None else info
        return np.empty(g, f32), np.empty(l, f32), np.empty(c, f32), np.empty(h, f32), info

    def _kernel_actions(self, actions: np.ndarray) -> np.ndarray:
        """``actions`` as a C-contiguous int64 (B, N) array (the kernels' layout), else a ValueError
        naming what is wrong; the range is checked by the step."""
        a = actions
        if not (type(a) is np.ndarray and a.dtype == np.int64 and a.shape == self._action_shape):
            a = np.asarray(a)
            if a.shape != self._action_shape:
                raise ValueError(
                    f"actions must have shape (num_worlds, num_robots) = {self._action_shape}, got {a.shape}"
                )
            if not np.issubdtype(a.dtype, np.integer):
                raise ValueError(f"actions must be integers, got dtype {a.dtype}")
        return np.ascontiguousarray(a, np.int64)

    def _raise_out_of_range(self, a: np.ndarray, bad: int) -> None:
        """The error for action ``bad`` (``b * N + i``) out of [0, 4); nothing for -1."""
        if bad >= 0:
            b, i = divmod(bad, self.num_robots)
            raise ValueError(
                f"primitive action {int(a[b, i])} of robot_{i} in world {b} is out of range [0, 4)"
            )

    def observe(self, worlds: np.ndarray) -> None:
        """Rebuild the macro-observations of the worlds in the bool mask ``worlds`` (B,)."""
        self.chunks.run(lambda w: self.observe_chunk(worlds, w), worlds)

    def observe_chunk(self, worlds: np.ndarray, chunk: slice) -> None:
        """:meth:`observe` of the worlds of ``chunk`` (one thread's share)."""
        k, w = self.state.kernel_chunk(chunk), chunk
        shown = k.heard_pos  # where each remembered teammate is drawn
        if self.heading:
            shown = estimated_cells(k.heard_tick, k.heard_pos, k.heard_goal, k.ticks, k.speed)
        build_observations(
            worlds[w],
            k.belief,
            k.used_occ,
            self.noisy,
            k.pos,
            k.cls,
            k.comp,
            k.goal,
            k.target,
            self.obs_global[w],
            self.obs_local[w],
            self.memory,
            k.heard_tick,
            shown,
            k.heard_knows,
        )

    # -- read-outs -----------------------------------------------------------------------------
    def knows_target(self) -> np.ndarray:
        """(B, N) bool: which robots' beliefs contain the target cell."""
        st = self.state
        b = np.arange(self.num_worlds)
        return (st.belief[b, :, st.target[:, 0], st.target[:, 1]] & TARGET_BIT) != 0

    def explored_fraction(self) -> np.ndarray:
        """(B,) fraction of the interior cells (outer wall ring excluded) the team has explored."""
        inner = self.state.belief[:, :, 1:-1, 1:-1] & EXPLORED
        return inner.any(axis=1).mean(axis=(1, 2))

    def ground_truth(self, b: int | None = 0) -> np.ndarray:
        """(4 + C, H, W) float32 ground truth of world b — or (B, 4 + C, H, W) of every world for
        ``b=None`` — in {0, 1}: occupied (walls, obstacles), target, clues, explored by any robot, then
        one channel per class with that class's robot cells."""
        st = self.state
        worlds = slice(None) if b is None else [b]
        g, cls, pos = st.grid[worlds], st.cls[worlds], st.pos[worlds]
        out = np.zeros((len(g), 4 + self.cfg.num_classes) + self.shape, np.float32)
        out[:, 0] = (g == WALL) | (g == OBSTACLE)
        out[:, 1] = g == TARGET
        out[:, 2] = g == CLUE
        out[:, 3] = (st.belief[worlds] & EXPLORED).any(axis=1)
        out[np.arange(len(g))[:, None], 4 + cls, pos[..., 0], pos[..., 1]] = 1.0
        return out if b is None else out[0]


def episode_rules(cfg: EnvConfig, speed_of: np.ndarray, rescue_of: np.ndarray, comm_of: np.ndarray) -> tuple:
    """What :func:`~.kernels.episodes.load_episodes` draws an episode of ``cfg`` from (its arguments
    after the codes): the team's slots, the classes' speeds and roles, the communication ranges, the
    map generator's numbers, and the fixed layout if there is one."""
    team = [-1 if slot == "random" else cfg.class_index(slot) for slot in cfg.team]
    lay = parse_layout(cfg.layout) if cfg.layout is not None else None
    layout = (
        (np.zeros((0, 0), np.uint8), np.zeros((0, 2), np.int64), np.zeros(0, np.int64), np.zeros(2, np.int64))
        if lay is None
        else (lay.grid, lay.robots, np.array(lay.headings, np.int64), np.array(lay.target, np.int64))
    )
    size = cfg.map_size
    return (np.array(team, np.int64), np.array([cfg.class_index(k) for k in cfg.random_classes], np.int64),
            speed_of, rescue_of, comm_of, size, cfg.obstacles, cfg.wall_prob, target_exclusion_side(size),
            first_block(cfg), *layout)  # fmt: skip


def world_key(seed: int, episode: int) -> int:
    """The key of episode ``episode`` of ``seed`` (:attr:`BatchedWorld.world_keys`): 63 bits of a sibling
    of the episode's map and dynamics streams, a one-way function of ``(seed, episode)``."""
    seq = np.random.SeedSequence(int(seed), spawn_key=(int(episode), 2))
    return int(seq.generate_state(1, np.uint64)[0] >> np.uint64(1))
