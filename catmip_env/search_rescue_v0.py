"""PettingZoo adapter: the CATMiP search-and-rescue world as a ``ParallelEnv`` (one world).

Use :func:`parallel_env` (or :func:`env` for the AEC API through ``parallel_to_aec``)::

    from catmip_env import search_rescue_v0
    env = search_rescue_v0.parallel_env(preset="task2", level="macro", comm_sigma=4.0)
    obs, infos = env.reset(seed=0)
"""

from __future__ import annotations

import functools
import warnings
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv
from pettingzoo.utils import parallel_to_aec, wrappers

from catmip_env.config import EnvConfig, make_config
from catmip_env.engine import BatchedEngine
from catmip_env.events import GOAL_MODES, INVALID_ACTION_MODES, EventEngine
from catmip_env.render import render_ansi, render_world
from catmip_env.types import OBS_SCALE, PRIMITIVE_ACTIONS, global_channels, local_channels

__all__ = ["SearchRescueEnv", "parallel_env", "env", "raw_env", "LEVELS"]

LEVELS = ("macro", "primitive")


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
    cell: its current goal), meaning "keep your goal", and its action may be omitted. An active robot's
    out-of-range or masked action raises ``ValueError`` (``invalid_action="stay"`` substitutes "stay
    here"). Primitive: 0 turn left, 1 turn right, 2 forward, 3 stay; a slow robot executes an action
    only on ticks where ``info["can_act"] == 1``.

    **Observation** (``Dict``; ``compact_obs=True`` gives the maps as uint8, float = value * 0.25):

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
    ``knows_target``.

    **Arguments.** ``preset`` (``task1``, ``task2``, ``task3``, ``train``) or an ``EnvConfig``; any
    ``EnvConfig`` field as keyword (``comm_sigma``, ``slam_noise``, ``horizon_ticks``, ``max_ma_ticks``,
    ``activation``, ``synchronous``, ``window``, ``layout`` ...); ``level``; ``goal_mode``;
    ``invalid_action``; ``render_mode`` (``rgb_array``, ``human``, ``ansi``); ``compact_obs``;
    ``max_cycles`` (primitive: sets ``horizon_ticks``; macro: at most this many steps).
    ``reset(options={"episode_index": k})`` replays episode k of the current seed.

    **Version history.** v0: primitive and macro levels, window and cell goal modes.
    """

    metadata = {
        "name": "catmip_search_rescue_v0",
        "render_modes": ["rgb_array", "human", "ansi"],
        "is_parallelizable": True,
        "render_fps": 8,
    }

    def __init__(
        self,
        config: EnvConfig,
        level: str = "macro",
        goal_mode: str = "window",
        invalid_action: str = "raise",
        render_mode: str | None = None,
        compact_obs: bool = False,
        max_cycles: int | None = None,
    ) -> None:
        if level not in LEVELS:
            raise ValueError(f"unknown level {level!r}; supported levels: {list(LEVELS)}")
        if goal_mode not in GOAL_MODES:
            raise ValueError(f"unknown goal_mode {goal_mode!r}; choose one of {list(GOAL_MODES)}")
        if invalid_action not in INVALID_ACTION_MODES:
            raise ValueError(
                f"unknown invalid_action {invalid_action!r}; choose one of {list(INVALID_ACTION_MODES)}"
            )
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"unknown render_mode {render_mode!r}; supported: {self.metadata['render_modes']}"
            )
        if max_cycles is not None and max_cycles < 1:
            raise ValueError(f"max_cycles must be >= 1, got {max_cycles!r}")
        self.config = config
        self.level = level
        self.goal_mode = goal_mode
        self.render_mode = render_mode
        self.compact_obs = compact_obs
        self.max_cycles = max_cycles if level == "macro" else None
        if level == "macro":
            self.engine = EventEngine(config, 1, None, goal_mode=goal_mode, invalid_action=invalid_action)
            self.world = self.engine.world
            self.num_actions = self.engine.num_actions
        else:
            self.engine = self.world = BatchedEngine(config, num_worlds=1, seed=None)
            self.num_actions = len(PRIMITIVE_ACTIONS)
        self.possible_agents = [f"robot_{i}" for i in range(config.num_robots)]
        self.agent_name_mapping = {a: i for i, a in enumerate(self.possible_agents)}
        self.agents: list[str] = []
        self._n_cls = config.num_classes
        self._eye_cls = np.eye(self._n_cls, dtype=np.float32)
        self._eye_head = np.eye(4, dtype=np.float32)
        self._ones_mask = np.ones(self.num_actions, np.int8)
        self._actions = np.zeros((1, config.num_robots), np.int64)
        self._steps = 0
        self._fig = None
        h, w = config.map_shape
        self.state_space = spaces.Box(0.0, 1.0, (4 + self._n_cls, h, w), np.float32)

    # -- spaces --------------------------------------------------------------------------------
    @functools.cache  # noqa: B019 - one space object per agent, as PettingZoo asks
    def observation_space(self, agent: str) -> spaces.Dict:
        self._index(agent)
        cfg, c = self.config, self._n_cls
        h, w = cfg.map_shape
        big = 4 if self.compact_obs else 1.0
        dt = np.uint8 if self.compact_obs else np.float32

        def box(shape: tuple[int, ...]) -> spaces.Box:
            return spaces.Box(0, big, shape, dt)

        inner = {
            "global_map": box((global_channels(c), h, w)),
            "local_map": box((local_channels(c), cfg.local_size, cfg.local_size)),
            "agent_class": spaces.Box(0.0, 1.0, (c,), np.float32),
        }
        if self.level == "primitive":
            inner["heading"] = spaces.Box(0.0, 1.0, (4,), np.float32)
        return spaces.Dict(
            {"observation": spaces.Dict(inner), "action_mask": spaces.Box(0, 1, (self.num_actions,), np.int8)}
        )

    @functools.cache  # noqa: B019
    def action_space(self, agent: str) -> spaces.Discrete:
        self._index(agent)
        return spaces.Discrete(self.num_actions)

    def _index(self, agent: str) -> int:
        try:
            return self.agent_name_mapping[agent]
        except (KeyError, TypeError):
            raise ValueError(f"unknown robot id {agent!r}; robots are {self.possible_agents}") from None

    # -- API -----------------------------------------------------------------------------------
    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None):
        episode = None
        if options and "episode_index" in options:
            episode = [int(options["episode_index"])]
        if seed is not None:
            self.engine.seed(seed)
        self.engine.reset(episode_indices=episode)
        self.agents = self.possible_agents[:]
        self._steps = 0
        if self.render_mode == "human":
            self.render()
        return self._observations(), self._infos(event_ticks=0)

    def step(self, actions: dict[str, Any]):
        if not self.agents:
            raise RuntimeError("step() called after the episode ended; call reset() first")
        a = self._parse_actions(actions)
        if self.level == "macro":
            ev = self.engine.step(a)
            rewards_arr, term, trunc, ticks = (
                ev.rewards[0],
                ev.terminated[0],
                ev.truncated[0],
                ev.event_ticks[0],
            )
        else:
            res = self.engine.step(a)
            rewards_arr, term, trunc, ticks = res.rewards[0], res.terminated[0], res.truncated[0], 1
        self._steps += 1
        term = bool(term)
        trunc = bool(trunc) or (not term and self.max_cycles is not None and self._steps >= self.max_cycles)
        rewards = {ag: float(rewards_arr[i]) for i, ag in enumerate(self.possible_agents)}
        terms = dict.fromkeys(self.possible_agents, term)
        truncs = dict.fromkeys(self.possible_agents, trunc)
        obs, infos = self._observations(), self._infos(event_ticks=int(ticks))
        if term or trunc:
            self.agents = []
        if self.render_mode == "human":
            self.render()
        return obs, rewards, terms, truncs, infos

    def _parse_actions(self, actions: dict[str, Any]) -> np.ndarray:
        a = self._actions
        a[:] = 0
        given = set()
        for agent, action in actions.items():
            i = self._index(agent)
            try:
                v = int(action)
            except (TypeError, ValueError):
                raise ValueError(f"action of {agent} must be an int, got {action!r}") from None
            if self.level == "primitive" and (v != action or not 0 <= v < self.num_actions):
                raise ValueError(
                    f"action {action!r} of {agent} is out of range: primitive actions are "
                    f"0..{self.num_actions - 1} {PRIMITIVE_ACTIONS}"
                )
            a[0, i] = v
            given.add(agent)
        if self.level == "macro":
            needed = {ag for i, ag in enumerate(self.possible_agents) if self.engine.active[0, i]}
            for i, ag in enumerate(self.possible_agents):
                if ag in needed and ag in given and not 0 <= a[0, i] < self.num_actions:
                    raise ValueError(
                        f"action {a[0, i]} of {ag} is out of range: {self.goal_mode} actions are "
                        f"0..{self.num_actions - 1}"
                    )
            missing = sorted(needed - given)
            if missing:
                raise ValueError(f"missing actions for active robots {missing}")
        else:
            missing = sorted(set(self.agents) - given)
            if missing:
                raise ValueError(f"missing actions for robots {missing}")
        return a

    def _observations(self) -> dict[str, dict[str, Any]]:
        world, st = self.world, self.world.state
        g, l = world.obs_global[0], world.obs_local[0]
        if self.compact_obs:
            g, l = g.copy(), l.copy()
        else:
            g = g.astype(np.float32) * np.float32(OBS_SCALE)
            l = l.astype(np.float32) * np.float32(OBS_SCALE)
        macro = self.level == "macro"
        out = {}
        for i, agent in enumerate(self.possible_agents):
            inner = {"global_map": g[i], "local_map": l[i], "agent_class": self._eye_cls[st.cls[0, i]].copy()}
            if not macro:
                inner["heading"] = self._eye_head[st.heading[0, i]].copy()
            mask = self.engine.masks[0, i].copy() if macro else self._ones_mask.copy()
            out[agent] = {"observation": inner, "action_mask": mask}
        return out

    def _infos(self, event_ticks: int) -> dict[str, dict[str, int]]:
        st = self.world.state
        t = int(st.ticks[0])
        if self.level == "macro":
            active = self.engine.active[0]
            return {
                agent: {
                    "active": int(active[i]),
                    "agent_class": int(st.cls[0, i]),
                    "event_ticks": event_ticks,
                    "tick": t,
                    "neighbourhood": int(st.comp[0, i]),
                }
                for i, agent in enumerate(self.possible_agents)
            }
        knows = self.world.knows_target()[0]
        return {
            agent: {
                "agent_class": int(st.cls[0, i]),
                "tick": t,
                "neighbourhood": int(st.comp[0, i]),
                "can_act": int(t % st.speed[0, i] == 0),
                "knows_target": int(knows[i]),
            }
            for i, agent in enumerate(self.possible_agents)
        }

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
        import matplotlib.pyplot as plt  # human mode: a live matplotlib window

        if self._fig is None:
            self._fig, ax = plt.subplots()
            ax.set_axis_off()
            self._im = ax.imshow(frame)
        else:
            self._im.set_data(frame)
        self._fig.canvas.draw_idle()
        plt.pause(1e-3)
        return None

    def close(self) -> None:
        if self._fig is not None:
            import matplotlib.pyplot as plt

            plt.close(self._fig)
            self._fig = None


def parallel_env(
    preset: str | EnvConfig = "task2",
    level: str = "macro",
    goal_mode: str = "window",
    invalid_action: str = "raise",
    render_mode: str | None = None,
    compact_obs: bool = False,
    max_cycles: int | None = None,
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
    )


def raw_env(**kwargs: Any):
    """The AEC env (``parallel_to_aec``) without wrappers."""
    return parallel_to_aec(parallel_env(**kwargs))


def env(**kwargs: Any):
    """The AEC env with PettingZoo's order-enforcing wrapper."""
    return wrappers.OrderEnforcingWrapper(raw_env(**kwargs))
