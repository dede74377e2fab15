"""PettingZoo adapter: the CATMiP search-and-rescue world as a ``ParallelEnv`` (B = 1 engine).

Use :func:`parallel_env` (or :func:`env` for the AEC API through ``parallel_to_aec``)::

    from catmip_env import search_rescue_v0
    env = search_rescue_v0.parallel_env(preset="task2", comm_sigma=4.0, render_mode="rgb_array")
    obs, infos = env.reset(seed=0)
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv
from pettingzoo.utils import parallel_to_aec, wrappers

from catmip_env.config import EnvConfig, make_config
from catmip_env.engine import BatchedEngine
from catmip_env.render import render_ansi, render_world
from catmip_env.types import OBS_SCALE, PRIMITIVE_ACTIONS, global_channels, local_channels

__all__ = ["SearchRescueEnv", "parallel_env", "env", "raw_env"]

LEVELS = ("primitive",)


class SearchRescueEnv(ParallelEnv):
    """Heterogeneous robots search an unknown gridworld for a target and rescue it (CATMiP).

    **World.** An S x S map of rooms joined by 1-cell doorways, single-cell obstacles, and one
    impassable target surrounded by see-through clue cells (SPEC §1.1). Robots start in a random
    corner. Each robot keeps its own belief map from a 7x7 line-of-sight view ahead of it; beliefs are
    OR-merged inside communication neighbourhoods every tick (full communication, or links with
    probability exp(-d^2/sigma^2)); optional SLAM noise flips the occupancy the robot uses.

    **Robots and classes.** Agents ``robot_0 ... robot_{N-1}``; each has a class (default ``rescuer``:
    one action every 2 ticks, can rescue; ``explorer``: every tick). The class is in the observation
    and in ``info["agent_class"]`` (the ``train`` preset draws one robot's class per episode).

    **Action space** (``level="primitive"``): ``Discrete(4)`` every tick —
    0 turn left, 1 turn right, 2 forward, 3 stay. A slow robot executes an action only on ticks
    where ``info["can_act"] == 1``; actions given on its other ticks are ignored.

    **Observation** (``Dict``; ``compact_obs=True`` gives uint8 maps with float = value * 0.25):

    ============================== ===================== ========= =====================================
    key                            shape                 dtype     meaning
    ============================== ===================== ========= =====================================
    observation/global_map         (5 + C, H, W)         float32   explored, occupied, target (3x3) /
                                                                   clues (0.25), own goal (empty at this
                                                                   level), other robots of each class in
                                                                   the neighbourhood (3x3), own position
    observation/local_map          (4 + C, L, L)         float32   same channels (no own position), single
                                                                   cells, centred; outside = explored +
                                                                   occupied
    observation/agent_class        (C,)                  float32   class one-hot
    observation/heading            (4,)                  float32   heading one-hot E, S, W, N
    action_mask                    (4,)                  int8      all ones (every primitive is legal)
    ============================== ===================== ========= =====================================

    **Rewards** (per robot, per tick): -0.05 per successful forward move; ``collision_penalty``
    (default 0) when a forward move hits a wall, obstacle or the target; every robot gets
    ``100 (1 - 0.9 t/h)`` on the tick the target first becomes known (reset counts as t = 0, paid with
    the first step) and ``300 (1 - 0.9 t/h)`` on success.

    **Termination / truncation.** Success (a rescuer that knows the target stands orthogonally next
    to it at the end of a tick) terminates every robot; reaching ``horizon_ticks`` truncates every
    robot. ``state()`` is the ground truth, ``(4 + C, H, W)`` float32: occupied, target, clues,
    explored by anyone, robots of each class.

    **Info** (fixed numeric keys): ``agent_class``, ``tick``, ``neighbourhood`` (component label),
    ``can_act`` (executes an action on the next tick), ``knows_target``.

    **Arguments.** ``preset`` (``task1``, ``task2``, ``task3``, ``train``) or ``config``; any
    :class:`~catmip_env.EnvConfig` field as keyword override; ``level``; ``render_mode``
    (``rgb_array``, ``human``, ``ansi``); ``compact_obs``; ``max_cycles`` (alias of
    ``horizon_ticks``). ``reset(options={"episode_index": k})`` replays episode k of the seed.

    **Version history.** v0: first release (primitive level).
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
        level: str = "primitive",
        render_mode: str | None = None,
        compact_obs: bool = False,
    ) -> None:
        if level not in LEVELS:
            raise ValueError(f"unknown level {level!r}; supported levels: {list(LEVELS)}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"unknown render_mode {render_mode!r}; supported: {self.metadata['render_modes']}"
            )
        self.config = config
        self.level = level
        self.render_mode = render_mode
        self.compact_obs = compact_obs
        self.engine = BatchedEngine(config, num_worlds=1, seed=None)
        self.possible_agents = [f"robot_{i}" for i in range(config.num_robots)]
        self.agent_name_mapping = {a: i for i, a in enumerate(self.possible_agents)}
        self.agents: list[str] = []
        self._n_cls = config.num_classes
        self._eye_cls = np.eye(self._n_cls, dtype=np.float32)
        self._eye_head = np.eye(4, dtype=np.float32)
        self._mask = np.ones(len(PRIMITIVE_ACTIONS), np.int8)
        self._actions = np.zeros((1, config.num_robots), np.int64)
        self._fig = None
        h, w = config.map_shape
        self.state_space = spaces.Box(0.0, 1.0, (4 + self._n_cls, h, w), np.float32)

    # -- spaces --------------------------------------------------------------------------------
    @functools.cache  # noqa: B019 - one space object per agent, as PettingZoo asks
    def observation_space(self, agent: str) -> spaces.Dict:
        self._index(agent)
        cfg, c = self.config, self._n_cls
        h, w = cfg.map_shape
        big = 4.0 if self.compact_obs else 1.0
        dt = np.uint8 if self.compact_obs else np.float32

        def box(shape: tuple[int, ...]) -> spaces.Box:
            return spaces.Box(0, big, shape, dt)

        return spaces.Dict(
            {
                "observation": spaces.Dict(
                    {
                        "global_map": box((global_channels(c), h, w)),
                        "local_map": box((local_channels(c), cfg.local_size, cfg.local_size)),
                        "agent_class": spaces.Box(0.0, 1.0, (c,), np.float32),
                        "heading": spaces.Box(0.0, 1.0, (4,), np.float32),
                    }
                ),
                "action_mask": spaces.Box(0, 1, (len(PRIMITIVE_ACTIONS),), np.int8),
            }
        )

    @functools.cache  # noqa: B019
    def action_space(self, agent: str) -> spaces.Discrete:
        self._index(agent)
        return spaces.Discrete(len(PRIMITIVE_ACTIONS))

    def _index(self, agent: str) -> int:
        try:
            return self.agent_name_mapping[agent]
        except KeyError:
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
        if self.render_mode == "human":
            self.render()
        return self._observations(), self._infos()

    def step(self, actions: dict[str, Any]):
        if not self.agents:
            raise RuntimeError("step() called after the episode ended; call reset() first")
        n = self.config.num_robots
        a = self._actions
        seen = 0
        for agent, action in actions.items():
            i = self._index(agent)
            try:
                v = int(action)
            except (TypeError, ValueError):
                raise ValueError(f"action of {agent} must be an int, got {action!r}") from None
            if v != action or not 0 <= v < len(PRIMITIVE_ACTIONS):
                raise ValueError(
                    f"action {action!r} of {agent} is out of range: primitive actions are "
                    f"0..{len(PRIMITIVE_ACTIONS) - 1} {PRIMITIVE_ACTIONS}"
                )
            a[0, i] = v
            seen += 1
        if seen != n:
            missing = sorted(set(self.agents) - set(actions))
            raise ValueError(f"missing actions for robots {missing}")
        res = self.engine.step(a)
        done_term, done_trunc = bool(res.terminated[0]), bool(res.truncated[0])
        rewards = {ag: float(res.rewards[0, i]) for i, ag in enumerate(self.possible_agents)}
        terms = dict.fromkeys(self.possible_agents, done_term)
        truncs = dict.fromkeys(self.possible_agents, done_trunc)
        obs, infos = self._observations(), self._infos()
        if done_term or done_trunc:
            self.agents = []
        if self.render_mode == "human":
            self.render()
        return obs, rewards, terms, truncs, infos

    def _observations(self) -> dict[str, dict[str, Any]]:
        eng, st = self.engine, self.engine.state
        g, l = eng.obs_global[0], eng.obs_local[0]
        if not self.compact_obs:
            g = g.astype(np.float32) * np.float32(OBS_SCALE)
            l = l.astype(np.float32) * np.float32(OBS_SCALE)
        else:
            g, l = g.copy(), l.copy()
        out = {}
        for i, agent in enumerate(self.possible_agents):
            out[agent] = {
                "observation": {
                    "global_map": g[i],
                    "local_map": l[i],
                    "agent_class": self._eye_cls[st.cls[0, i]].copy(),
                    "heading": self._eye_head[st.heading[0, i]].copy(),
                },
                "action_mask": self._mask.copy(),
            }
        return out

    def _infos(self) -> dict[str, dict[str, int]]:
        st = self.engine.state
        t = int(st.ticks[0])
        knows = self.engine.knows_target()[0]
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
        return self.engine.ground_truth(0)

    def render(self):
        if self.render_mode is None:
            import warnings

            warnings.warn("render() called without a render_mode", stacklevel=2)
            return None
        if self.render_mode == "ansi":
            return render_ansi(self.engine, 0)
        frame = render_world(self.engine, 0)
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
    level: str = "primitive",
    render_mode: str | None = None,
    compact_obs: bool = False,
    max_cycles: int | None = None,
    **overrides: Any,
) -> SearchRescueEnv:
    """The Parallel env for a preset (or config) with ``EnvConfig`` field overrides.

    ``max_cycles`` (PettingZoo's name) sets ``horizon_ticks`` at the primitive level.
    """
    if max_cycles is not None:
        overrides["horizon_ticks"] = int(max_cycles)
    cfg = make_config(preset, **overrides)
    return SearchRescueEnv(cfg, level=level, render_mode=render_mode, compact_obs=compact_obs)


def raw_env(**kwargs: Any):
    """The AEC env (``parallel_to_aec``) without wrappers."""
    return parallel_to_aec(parallel_env(**kwargs))


def env(**kwargs: Any):
    """The AEC env with PettingZoo's order-enforcing wrapper."""
    return wrappers.OrderEnforcingWrapper(raw_env(**kwargs))
