"""PettingZoo adapter: the CATMiP search-and-rescue world as a ``ParallelEnv`` (one world).

Use :func:`parallel_env` (or :func:`env` for the AEC API through ``parallel_to_aec``)::

    from catmip_env.envs import search_rescue_v0
    env = search_rescue_v0.parallel_env(preset="task2", level="macro", comm_sigma=4.0)
    obs, infos = env.reset(seed=0)

``obs_format="flat"`` gives every robot one float32 ``Box`` vector (what SuperSuit's wrappers and
vector-env converters take) with the action mask in ``infos[robot]["action_mask"]``.

**Versioning** (PettingZoo's rule). The suffix is the environment's version: any change that can move
results — the dynamics, rewards, observations or spaces, termination, the random streams, the map
generator, or a default — renames it ``search_rescue_v1`` (registered as ``catmip/SearchRescue-v1``), so
that results reported on ``v0`` are never compared with another world unawares. A new option whose
default keeps the old behaviour (an ``EnvConfig`` field such as ``teammate_memory``), a fix that only
changes an error message, and speed-ups that keep every episode identical keep the suffix.
``tests/env/test_fingerprint.py`` (golden hashes of whole episodes) and the frozen map sets
(``catmip_env/maps/frozen_maps/``, checked by every evaluation) fail on a change that moves results.

**Version history.**

* ``v0`` (catmip 0.1.0 and 1.0.0; the current and only version): primitive and macro (decision-event)
  levels, window and cell goal modes, the dict and flat observation formats; an invalid action
  becomes "stay" and is flagged (``invalid_action="raise"`` is the strict mode). Its dynamics were
  developed before the first release and are frozen as of 1.0.0.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv
from pettingzoo.utils import parallel_to_aec, wrappers

from catmip_env.config import EnvConfig, make_config
from catmip_env.constants import PRIMITIVE_ACTIONS
from catmip_env.engines.events import GOAL_MODES, INVALID_ACTION_MODES, EventEngine
from catmip_env.engines.world import BatchedWorld, episode_index_array
from catmip_env.envs.render import RENDER_FPS, LiveWindow, render_ansi, render_world
from catmip_env.envs.spaces import (
    LEVELS,
    OBS_FORMATS,
    flat_layout,
    integer_action,
    macro_infos,
    macro_observations,
    observation_space,
    parse_actions,
    part_spaces,
    plain_primitives,
    primitive_outputs,
    replace_invalid_primitives,
    state_space,
)

__all__ = ["SearchRescueEnv", "parallel_env", "env", "raw_env", "LEVELS", "OBS_FORMATS", "integer_action"]


class SearchRescueEnv(ParallelEnv):
    """Heterogeneous robots search an unknown gridworld for a target and rescue it (CATMiP).

    **World.** An S x S map of rooms joined by 1-cell doorways, single-cell obstacles, and one
    impassable target surrounded by see-through clue cells. Robots start in a random corner. Each
    robot keeps its own belief map from a 7x7 line-of-sight view ahead of it; beliefs are OR-merged
    inside communication neighbourhoods every tick (full communication, or links with probability
    exp(-d^2/sigma^2)); optional SLAM noise flips the occupancy a robot uses.

    **Robots and classes.** Agents ``robot_0 ... robot_{N-1}``; each has a class (default
    ``rescuer``: one primitive action every 2 ticks, can rescue; ``explorer``: every tick). The class
    is in the observation and ``info["agent_class"]`` (the ``train`` preset draws one robot's class per
    episode).

    **Levels.** ``level="macro"`` (default, the paper's setting): one ``step()`` = one *decision
    event*. Actions are goals; a low-level planner drives each robot to its goal tick by tick, and a
    robot decides again when its macro-action ends (goal reached, goal unreachable or occupied, target
    first learned, ``max_ma_ticks`` elapsed) and its activation rule fires (``activation=(t_min,
    t_max)``: co-activation of two or more ready robots of a neighbourhood, else alone at a personal
    deadline; ``synchronous=True``: everyone every ``max_ma_ticks`` ticks). At ``reset`` every robot
    decides. ``level="primitive"``: one ``step()`` = one tick with ``Discrete(4)`` actions.

    **Action space.** Macro, ``goal_mode="window"``: ``Discrete(D*D)`` (D = ``window``, 7 → 49),
    action ``a`` = goal offset ``(a // D - D//2, a % D - D//2)`` (row, col) from the robot, the centre
    = stay. ``goal_mode="cell"``: ``Discrete(H*W)``, action ``r * W + c`` = goal cell. Only *active*
    robots' actions are applied; a busy robot's mask allows exactly one action (window: the centre;
    cell: its current goal), meaning "keep your goal", and its action may be omitted. Primitive: 0 turn
    left, 1 turn right, 2 forward, 3 stay; a slow robot executes an action only on ticks where
    ``info["can_act"] == 1``.

    **Invalid actions.** An applied action that is out of range or masked is replaced by "stay"
    (macro: a goal on the robot's own cell; primitive: action 3) and flagged in that robot's info
    (``invalid_action`` = 1 in the infos of that step, ``invalid_actions`` counts them per episode),
    so that any sampler — PettingZoo's test battery samples without the mask — can drive the env.
    ``invalid_action="raise"`` is the strict mode: a ``ValueError`` names the robot, the action and
    why. Any integer counts, however large (``2**63`` is out of range, not an overflow). A non-integer
    action (``2.5``, a bool, a string, an array) raises ``ValueError`` in both modes.

    **Observation** (``obs_format="dict"``, a ``Dict``; ``compact_obs=True`` gives the maps as uint8,
    float = value * 0.25):

    ========================= ============== ======= =================================================
    key                       shape          dtype   meaning
    ========================= ============== ======= =================================================
    observation/global_map    (5 + C, H, W)  float32 explored, occupied, target (3x3 of 1) / clues
                                                     (0.25), own goal, other robots of each class in
                                                     the neighbourhood (3x3), own position (3x3)
    observation/local_map     (4 + C, L, L)  float32 same channels (no own position), single cells,
                                                     centred (L = 7); outside = explored + occupied
    observation/agent_class   (C,)           float32 class one-hot
    observation/heading       (4,)           float32 heading one-hot E, S, W, N (primitive only)
    action_mask               (A,)           int8    1 = allowed (A = D*D, H*W, or 4)
    ========================= ============== ======= =================================================

    ``obs_format="flat"``: one ``Box(0, 1, (F,), float32)`` per robot, the parts above (without the
    mask) raveled in C order and concatenated in table order; ``flat_layout[key]`` = (slice, shape).
    The mask is then ``info["action_mask"]`` (PettingZoo's and TorchRL's other place for it).

    Invalid goals (from the robot's clean belief): outside the interior, known occupied (wall,
    obstacle, target), another neighbourhood member's cell, or a cell whose in-bounds 4-neighbours are
    all known occupied; unexplored cells are allowed; "stay" is always allowed.

    **Rewards.** Per robot: -0.05 per successful forward move, ``collision_penalty`` (default 0) per
    forward move into a wall, obstacle or the target; to every robot ``100 (1 - 0.9 t/h)`` on the
    tick the target first becomes known (t = 0 at reset: paid with the first step) and
    ``300 (1 - 0.9 t/h)`` on success. At the macro level a step's reward is the sum of the robot's
    primitive rewards since the previous event.

    **Termination / truncation.** Success (a rescuer that knows the target stands orthogonally next
    to it at the end of a tick) terminates every robot; ``horizon_ticks`` (or ``max_cycles`` steps)
    truncates every robot. All robots stay in ``agents`` until then. ``state()`` is the ground truth,
    ``(4 + C, H, W)`` float32: occupied, target, clues, explored by anyone, robots of each class.

    **Info** (fixed numeric keys). Macro: ``active`` (1 = must choose now), ``agent_class``,
    ``event_ticks`` (ticks since the previous event), ``tick``, ``neighbourhood`` (component label =
    lowest member id). Primitive: ``agent_class``, ``tick``, ``neighbourhood``, ``can_act``,
    ``knows_target``. Both: ``invalid_action``, ``invalid_actions``; flat format: ``action_mask``.

    **Arguments.** ``preset`` (``task1``, ``task2``, ``task3``, ``train``) or an ``EnvConfig``; any
    ``EnvConfig`` field as keyword (``comm_sigma``, ``slam_noise``, ``horizon_ticks``, ``max_ma_ticks``,
    ``activation``, ``synchronous``, ``window``, ``layout`` ...); ``level``; ``goal_mode``;
    ``invalid_action`` (``stay``, ``raise``); ``obs_format`` (``dict``, ``flat``); ``render_mode``
    (``rgb_array``, ``human``, ``ansi``); ``compact_obs`` (dict format only); ``max_cycles``
    (primitive: sets ``horizon_ticks``; macro: at most this many steps).
    ``reset(options={"episode_index": k})`` replays episode k of the current seed.

    **Version history** and the rule that bumps the suffix: the module's docstring.
    """

    metadata = {
        "name": "catmip_search_rescue_v0",
        "render_modes": ["rgb_array", "human", "ansi"],
        "is_parallelizable": True,
        "render_fps": RENDER_FPS,
    }

    def __init__(
        self,
        config: EnvConfig,
        level: str = "macro",
        goal_mode: str = "window",
        invalid_action: str = "stay",
        render_mode: str | None = None,
        compact_obs: bool = False,
        max_cycles: int | None = None,
        obs_format: str = "dict",
    ) -> None:
        for name, value, allowed in (
            ("level", level, LEVELS),
            ("goal_mode", goal_mode, GOAL_MODES),
            ("invalid_action", invalid_action, INVALID_ACTION_MODES),
            ("obs_format", obs_format, OBS_FORMATS),
            ("render_mode", render_mode, (None, *self.metadata["render_modes"])),
        ):
            if value not in allowed:
                raise ValueError(f"unknown {name} {value!r}; choose one of {list(allowed)}")
        if compact_obs and obs_format == "flat":
            raise ValueError("compact_obs=True applies to obs_format='dict' only; the flat format is float32")
        if max_cycles is not None and max_cycles < 1:
            raise ValueError(f"max_cycles must be >= 1, got {max_cycles!r}")
        self.config = config
        self.level = level
        self.goal_mode = goal_mode
        self.invalid_action = invalid_action
        self.obs_format = obs_format
        self.render_mode = render_mode
        self.compact_obs = compact_obs
        self.max_cycles = max_cycles if level == "macro" else None
        if level == "macro":
            self.engine = EventEngine(config, 1, None, goal_mode=goal_mode, invalid_action=invalid_action)
            self.world = self.engine.world
            self.num_actions = self.engine.num_actions
        else:
            self.engine = self.world = BatchedWorld(config, num_worlds=1, seed=None)
            self.num_actions = len(PRIMITIVE_ACTIONS)
        n = config.num_robots
        self.possible_agents = [f"robot_{i}" for i in range(n)]
        self.agent_name_mapping = {a: i for i, a in enumerate(self.possible_agents)}
        self.agents: list[str] = []
        self._actions = np.zeros((1, n), np.int64)
        self._invalid = np.zeros(n, np.bool_)  # actions replaced by "stay" at the last step
        self._invalid_count = np.zeros(n, np.int64)  # ... and since reset
        self._steps = 0
        self._flagged = False  # whether _invalid may hold a True (primitive level)
        self._all_legal = np.ones((n, self.num_actions), np.int8)
        # the primitive level's outputs, from the view the world writes with each tick (arrays, no views:
        # a pickled env keeps them the same objects)
        agents, legal = self.possible_agents, self._all_legal
        self._output_args = (agents, legal, self._invalid, self._invalid_count, obs_format)
        self._window: LiveWindow | None = None
        self.state_space = state_space(config)
        parts = part_spaces(config, level, compact_obs)
        self.flat_layout = flat_layout(parts)  # part -> (slice, shape) of the flat vector
        # one space object per robot (PettingZoo seeds each robot's space on its own)
        self.observation_spaces = {
            a: observation_space(part_spaces(config, level, compact_obs), obs_format, self.num_actions)
            for a in self.possible_agents
        }
        self.action_spaces = {a: spaces.Discrete(self.num_actions) for a in self.possible_agents}

    # -- spaces --------------------------------------------------------------------------------
    def observation_space(self, agent: str) -> spaces.Space:
        self._index(agent)  # a clear error for unknown ids
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Discrete:
        self._index(agent)
        return self.action_spaces[agent]

    def _index(self, agent: str) -> int:
        try:
            return self.agent_name_mapping[agent]
        except (KeyError, TypeError):
            raise ValueError(f"unknown robot id {agent!r}; robots are {self.possible_agents}") from None

    # -- API -----------------------------------------------------------------------------------
    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None):
        episode = None
        if options and "episode_index" in options:
            episode = episode_index_array([options["episode_index"]], 'options["episode_index"]')
        if seed is not None:
            self.engine.seed(seed)
        self.engine.reset(episode_indices=episode)
        self.agents = self.possible_agents[:]
        self._steps = 0
        self._invalid[:] = False
        self._invalid_count[:] = 0
        self._flagged = False
        if self.render_mode == "human":
            self.render()
        return self._outputs(event_ticks=0)

    def step(self, actions: dict[str, Any]):
        if not self.agents:
            raise RuntimeError("step() called after the episode ended; call reset() first")
        if self.level == "primitive":
            return self._step_primitive(actions)
        ev = self.engine.step(self._parse_actions(actions))  # raises on, or replaces, invalid goals
        self._invalid[:] = self.engine.invalid[0]
        self._invalid_count += self._invalid
        self._steps += 1
        term = bool(ev.terminated[0])
        trunc = bool(ev.truncated[0]) or (
            not term and self.max_cycles is not None and self._steps >= self.max_cycles
        )
        return self._ended(ev.rewards[0], term, trunc, *self._outputs(event_ticks=int(ev.event_ticks[0])))

    def _step_primitive(self, actions: dict[str, Any]):
        a = self._actions
        if not plain_primitives(actions, self.possible_agents, a[0]):  # else parsed in full
            a = self._parse_actions(actions)
            self._invalid[:] = replace_invalid_primitives(
                a[0], self.possible_agents, self.invalid_action == "raise"
            )
            self._invalid_count += self._invalid
            self._flagged = True
        elif self._flagged:  # the last step replaced an action: this one none
            self._invalid[:] = False
            self._flagged = False
        self._steps += 1
        res, view = self.world.step_viewed(a)  # the tick and the observations in one kernel call
        outputs = primitive_outputs(view, *self._output_args, self._compact_maps())
        return self._ended(res.rewards[0], bool(res.terminated[0]), bool(res.truncated[0]), *outputs)

    def _ended(self, rewards: np.ndarray, term: bool, trunc: bool, obs: dict, infos: dict):
        """The step's five dicts; the episode over (``agents`` empty) on termination or truncation."""
        agents = self.possible_agents
        if term or trunc:
            self.agents = []
        if self.render_mode == "human":
            self.render()
        rewards_of = dict(zip(agents, rewards.tolist()))
        return obs, rewards_of, dict.fromkeys(agents, term), dict.fromkeys(agents, trunc), infos

    def _parse_actions(self, actions: dict[str, Any]) -> np.ndarray:
        """The (1, N) int64 action array (see :func:`catmip_env.envs.spaces.parse_actions`)."""
        macro, agents = self.level == "macro", self.possible_agents
        applies = self.engine.active[0] if macro else np.ones(len(agents), np.bool_)
        kind, strict = (self.goal_mode if macro else "primitive"), self.invalid_action == "raise"
        parse_actions(actions, agents, self._index, applies, kind, self.num_actions, strict, self._actions[0])
        return self._actions

    def _outputs(self, event_ticks: int) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
        """Every robot's observation and info."""
        if self.level == "primitive":
            return primitive_outputs(self.world.view(0), *self._output_args, self._compact_maps())
        obs, masks = macro_observations(
            self.engine, 0, self.possible_agents, self.obs_format, self.compact_obs
        )
        infos = macro_infos(self.engine, 0, self.possible_agents, event_ticks)
        for i, agent in enumerate(self.possible_agents):
            info = infos[agent]
            info["invalid_action"] = int(self._invalid[i])
            info["invalid_actions"] = int(self._invalid_count[i])
            if self.obs_format == "flat":
                info["action_mask"] = masks[i]
        return obs, infos

    def _compact_maps(self) -> tuple[np.ndarray, np.ndarray] | None:
        """``compact_obs``: world 0's uint8 maps (copied by the outputs); else None."""
        return (self.world.obs_global[0], self.world.obs_local[0]) if self.compact_obs else None

    def state(self) -> np.ndarray:
        return self.world.ground_truth(0)

    def render(self):
        if self.render_mode is None:
            warnings.warn("render() called without a render_mode", stacklevel=2)
            return None
        if self.render_mode == "ansi":
            return render_ansi(self.world, 0)
        frame = render_world(self.world, 0)
        if self.render_mode == "rgb_array":
            return frame
        if self._window is None:  # human mode: a live matplotlib window
            self._window = LiveWindow()
        self._window.show(frame)
        return None

    def close(self) -> None:
        if self._window is not None:
            self._window.close()
            self._window = None


def parallel_env(
    preset: str | EnvConfig = "task2",
    level: str = "macro",
    goal_mode: str = "window",
    invalid_action: str = "stay",
    render_mode: str | None = None,
    compact_obs: bool = False,
    max_cycles: int | None = None,
    obs_format: str = "dict",
    **overrides: Any,
) -> SearchRescueEnv:
    """The Parallel env for a preset (or config) with ``EnvConfig`` field overrides.

    ``max_cycles`` (PettingZoo's name): at the primitive level it sets ``horizon_ticks``; at the macro
    level the episode is truncated after that many decision events.
    """
    if max_cycles is not None and level == "primitive":
        overrides["horizon_ticks"] = int(max_cycles)
        max_cycles = None
    cfg = make_config(preset, **overrides)
    return SearchRescueEnv(
        cfg,
        level=level,
        goal_mode=goal_mode,
        invalid_action=invalid_action,
        render_mode=render_mode,
        compact_obs=compact_obs,
        max_cycles=max_cycles,
        obs_format=obs_format,
    )


def raw_env(**kwargs: Any):
    """The AEC env (``parallel_to_aec``) without wrappers."""
    return parallel_to_aec(parallel_env(**kwargs))


def env(**kwargs: Any):
    """The AEC env with PettingZoo's order-enforcing wrapper."""
    return wrappers.OrderEnforcingWrapper(raw_env(**kwargs))
