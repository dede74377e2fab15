"""Spaces of the PettingZoo adapter: observation parts, the flat layout, and action parsing.

An observation has named parts (``global_map``, ``local_map``, ``agent_class`` and, at the primitive
level, ``heading``), in table order. ``obs_format="dict"`` gives them as a ``Dict`` next to the action
mask; ``obs_format="flat"`` ravels them in C order and concatenates them in that order into one float32
``Box`` vector, whose layout is :func:`flat_layout`. The table itself is the class docstring of
:class:`catmip_env.envs.search_rescue_v0.SearchRescueEnv`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from gymnasium import spaces

from catmip_env.config import EnvConfig
from catmip_env.constants import OBS_SCALE, PRIMITIVE_ACTIONS, STAY, global_channels, local_channels

__all__ = [
    "LEVELS",
    "OBS_FORMATS",
    "FlatLayout",
    "part_spaces",
    "flat_layout",
    "observation_space",
    "state_space",
    "observation_parts",
    "macro_observations",
    "macro_infos",
    "robot_observations",
    "integer_action",
    "parse_actions",
    "replace_invalid_primitives",
]

LEVELS = ("macro", "primitive")
OBS_FORMATS = ("dict", "flat")

#: part -> (slice of the flat vector, shape of the part)
FlatLayout = dict[str, tuple[slice, tuple[int, ...]]]

_INT64 = np.iinfo(np.int64)


def part_spaces(cfg: EnvConfig, level: str, compact_obs: bool) -> dict[str, spaces.Box]:
    """The observation parts of one robot, in table (and flat-layout) order."""
    c = cfg.num_classes
    big, dt = (4, np.uint8) if compact_obs else (1.0, np.float32)
    parts = {
        "global_map": spaces.Box(0, big, (global_channels(c), *cfg.map_shape), dt),
        "local_map": spaces.Box(0, big, (local_channels(c), cfg.local_size, cfg.local_size), dt),
        "agent_class": spaces.Box(0.0, 1.0, (c,), np.float32),
    }
    if level == "primitive":
        parts["heading"] = spaces.Box(0.0, 1.0, (4,), np.float32)
    return parts


def flat_layout(parts: dict[str, spaces.Box]) -> FlatLayout:
    """Where each part lies in the flat vector: consecutive slices, in the order of ``parts``."""
    layout: FlatLayout = {}
    start = 0
    for key, box in parts.items():
        size = math.prod(box.shape)
        layout[key] = (slice(start, start + size), box.shape)
        start += size
    return layout


def observation_space(parts: dict[str, spaces.Box], obs_format: str, num_actions: int) -> spaces.Space:
    """One robot's observation space: ``Dict(observation=Dict(parts), action_mask=Box)``, or for
    ``obs_format="flat"`` one ``Box(0, 1, (F,), float32)`` (the mask then travels in the infos)."""
    if obs_format == "flat":
        size = sum(math.prod(box.shape) for box in parts.values())
        return spaces.Box(0.0, 1.0, (size,), np.float32)
    mask = spaces.Box(0, 1, (num_actions,), np.int8)
    return spaces.Dict({"observation": spaces.Dict(parts), "action_mask": mask})


def state_space(cfg: EnvConfig) -> spaces.Box:
    """The ground-truth ``state()``: ``(4 + C, H, W)`` float32 in {0, 1}."""
    return spaces.Box(0.0, 1.0, (4 + cfg.num_classes, *cfg.map_shape), np.float32)


def observation_parts(
    obs_global: np.ndarray,  # (N, 5 + C, H, W) uint8, float = value * OBS_SCALE
    obs_local: np.ndarray,  # (N, 4 + C, L, L) uint8
    class_onehot: np.ndarray,  # (N, C) float32
    heading_onehot: np.ndarray | None,  # (N, 4) float32, primitive level only
    compact_obs: bool,
) -> dict[str, np.ndarray]:
    """Every robot's observation parts (N, ...) in table order; the maps are new arrays (not the
    engine's buffers), float32 ``value * OBS_SCALE`` unless ``compact_obs``."""
    if compact_obs:
        g, l = obs_global.copy(), obs_local.copy()
    else:
        g = obs_global.astype(np.float32) * np.float32(OBS_SCALE)
        l = obs_local.astype(np.float32) * np.float32(OBS_SCALE)
    parts = {"global_map": g, "local_map": l, "agent_class": class_onehot}
    if heading_onehot is not None:
        parts["heading"] = heading_onehot
    return parts


def robot_observations(
    parts: dict[str, np.ndarray], masks: np.ndarray, obs_format: str, agents: list[str]
) -> dict[str, Any]:
    """``{agent: observation}`` from the parts (N, ...) and the (N, A) masks, in ``obs_format``."""
    n = len(agents)
    if obs_format == "flat":
        flat = np.concatenate([p.reshape(n, -1) for p in parts.values()], axis=1)
        return {agent: flat[i] for i, agent in enumerate(agents)}
    return {
        agent: {"observation": {k: p[i] for k, p in parts.items()}, "action_mask": masks[i]}
        for i, agent in enumerate(agents)
    }


def integer_action(agent: str, action: Any) -> int:
    """``action`` as an int. Python and numpy integers (0-d arrays too) and integral floats (``2.0``)
    are accepted; anything else — ``2.5``, a bool, a string, ``None``, an array with a shape — is a type
    error, not an invalid choice, and raises ``ValueError`` whatever ``invalid_action`` says."""
    if isinstance(action, (int, np.integer)) and not isinstance(action, bool):
        return int(action)  # the common case first: this runs for every robot at every step
    value = action.item() if isinstance(action, (np.ndarray, np.generic)) and np.ndim(action) == 0 else action
    integral = isinstance(value, int) or (isinstance(value, float) and value.is_integer())
    if isinstance(value, bool) or not integral:
        raise ValueError(
            f"action of {agent} must be an integer (Discrete action), got {action!r} of type "
            f"{type(action).__name__}"
        )
    return int(value)


def parse_actions(
    actions: dict[str, Any],
    agents: list[str],
    index: Callable[[str], int],  # robot id -> robot index; raises ValueError on unknown ids
    applies: np.ndarray,  # (N,) bool robots whose actions are applied now (the others may be omitted)
    kind: str,  # "window", "cell" (macro goal modes) or "primitive", for messages
    num_actions: int,
    strict: bool,  # invalid_action="raise"
    out: np.ndarray,  # (N,) int64, written; omitted robots get 0
) -> None:
    """The action of every robot from ``{agent: action}``; anything but a dict (TypeError), unknown ids,
    non-integers and missing robots raise. An integer no int64 holds (``2**63``) is out of range like
    ``-1``: strict mode raises naming it (for a robot whose action applies), else it is stored as -1 and
    replaced and flagged (or ignored, for a busy robot) with the other out-of-range actions."""
    if not isinstance(actions, Mapping):
        raise TypeError(
            f"actions must be a dict of robot id -> action ({{{agents[0]!r}: 0, ...}}), got "
            f"{type(actions).__name__}"
        )
    out[:] = 0  # omitted busy robots: ignored by the engine
    for agent, action in actions.items():
        i, value = index(agent), integer_action(agent, action)
        if not _INT64.min <= value <= _INT64.max:
            if strict and applies[i]:
                raise ValueError(
                    f"action {value} of {agent} is out of range: {kind} actions are "
                    f"0..{num_actions - 1} (invalid_action='stay' would replace it with 'stay')"
                )
            value = -1
        out[i] = value
    missing = sorted({ag for i, ag in enumerate(agents) if applies[i]} - set(actions))
    if missing:
        raise ValueError(f"missing actions for {'' if kind == 'primitive' else 'active '}robots {missing}")


def plain_primitives(actions: Any, agents: list[str], out: np.ndarray) -> bool:
    """Write the actions into ``out`` (N,) and say True when ``actions`` is a dict that holds every
    robot's, each a Python or numpy int in [0, 4): a primitive step's common case, taken in a microsecond
    or two. Else False, and :func:`parse_actions` takes them (and raises or flags as it says)."""
    if type(actions) is not dict or len(actions) != len(agents):
        return False
    try:
        values = [actions[agent] for agent in agents]
    except (KeyError, TypeError):
        return False
    for v in values:
        if not ((type(v) is int or type(v) is np.int64) and 0 <= v < 4):
            return False
    out[:] = values
    return True


def primitive_outputs(
    view: tuple[np.ndarray, ...],  # robot_view's outputs: maps, one-hots (N, ...) float32, infos (N, 5) int64
    agents: list[str],
    masks: np.ndarray,  # (N, 4) int8 all ones (copied)
    invalid: np.ndarray,  # (N,) bool: actions replaced at this step
    invalid_count: np.ndarray,  # (N,) int64: ... since reset
    obs_format: str = "dict",
    compact: tuple[np.ndarray, np.ndarray] | None = None,  # compact_obs: the world's uint8 maps, copied
) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
    """Every robot's observation and info at the primitive level, from the parts the world wrote in one
    kernel call (:func:`~catmip_env.kernels.primitive.robot_view`): the values of
    :func:`observation_parts` and :func:`robot_observations` (the flat format's mask in the infos)."""
    g, l, c, h, info = view
    if compact is not None:
        g, l = compact[0].copy(), compact[1].copy()
    masks = masks.copy()
    n = len(agents)
    if obs_format == "flat":
        obs = dict(zip(agents, np.concatenate([g.reshape(n, -1), l.reshape(n, -1), c, h], axis=1)))
    else:
        obs = {
            agent: {
                "observation": {"global_map": gi, "local_map": li, "agent_class": ci, "heading": hi},
                "action_mask": mi,
            }
            for agent, gi, li, ci, hi, mi in zip(agents, g, l, c, h, masks)
        }
    rows = info.tolist()
    t = rows[0][4]
    infos = {
        agent: {
            "agent_class": row[0],
            "tick": t,
            "neighbourhood": row[1],
            "can_act": row[2],
            "knows_target": row[3],
            "invalid_action": bad,
            "invalid_actions": count,
        }
        for agent, row, bad, count in zip(agents, rows, invalid.tolist(), invalid_count.tolist())
    }
    if obs_format == "flat":
        for i, agent in enumerate(agents):
            infos[agent]["action_mask"] = masks[i]
    return obs, infos


def replace_invalid_primitives(a: np.ndarray, agents: list[str], strict: bool) -> np.ndarray:
    """Apply the invalid-action policy to primitive actions ``a`` (N,) in place: out-of-range actions
    become "stay" (or, ``strict``, raise naming the first). Returns the (N,) bool replaced ones."""
    num_actions = len(PRIMITIVE_ACTIONS)
    bad = (a < 0) | (a >= num_actions)
    if not bad.any():
        return bad
    if strict:
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"action {a[i]} of {agents[i]} is out of range: primitive actions are "
            f"0..{num_actions - 1} {PRIMITIVE_ACTIONS} (invalid_action='stay' would replace it "
            f"with 'stay')"
        )
    a[bad] = STAY
    return bad


def macro_observations(
    engine, b: int, agents: list[str], obs_format: str = "dict", compact_obs: bool = False
) -> tuple[dict[str, Any], np.ndarray]:
    """World ``b``'s observations ``{agent: observation}`` as the macro env gives them (new arrays),
    and its (N, A) int8 action masks: one source for the env and for evaluating a PettingZoo-level
    policy on a batched engine (``catmip_rl.evaluation.user_policy``); ``engine``: an ``EventEngine``."""
    world, st = engine.world, engine.world.state
    class_onehot = np.eye(engine.cfg.num_classes, dtype=np.float32)[st.cls[b]]
    parts = observation_parts(world.obs_global[b], world.obs_local[b], class_onehot, None, compact_obs)
    masks = engine.masks[b].copy()
    return robot_observations(parts, masks, obs_format, agents), masks


def macro_infos(engine, b: int, agents: list[str], event_ticks: int) -> dict[str, dict[str, Any]]:
    """World ``b``'s macro-level infos without the invalid-action counters: ``active``,
    ``agent_class``, ``event_ticks`` (given: ticks since the previous event), ``tick``,
    ``neighbourhood``."""
    st = engine.state
    t = int(st.ticks[b])
    return {
        agent: {
            "active": int(engine.active[b, i]),
            "agent_class": int(st.cls[b, i]),
            "event_ticks": int(event_ticks),
            "tick": t,
            "neighbourhood": int(st.comp[b, i]),
        }
        for i, agent in enumerate(agents)
    }
