"""``catmip render``: one evaluation episode of a method as a GIF (the map of ``episode`` of ``seed``, as
:func:`~catmip_rl.evaluation.evaluate.evaluate` plays it)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from catmip_env.engines.events import EventEngine
from catmip_env.envs import render
from catmip_env.play import plays_one_world_at_a_time
from catmip_rl.evaluation.evaluate import EvalSetting
from catmip_rl.evaluation.methods import Method, make_policy, parse_method
from catmip_rl.evaluation.sandbox import close_policy

if TYPE_CHECKING:  # the planners need no torch
    from catmip_rl.amat.model import AMAT

__all__ = ["render_episode"]


def render_episode(
    method: str | Method,
    setting: EvalSetting,
    path: str | Path,
    episode: int = 0,
    seed: int = 0,
    fps: int | None = None,
    max_frames: int = 600,
    model: AMAT | None = None,
) -> Path:
    """GIF of one evaluation episode (the map of ``episode`` of ``seed``, as in :func:`evaluate`),
    one frame per tick (:func:`catmip_env.envs.render.render_episode`): robots, their goals, explored area,
    communication links; ``fps`` defaults to the env's ``metadata["render_fps"]``."""
    from catmip_env.envs.render import RENDER_FPS

    method = parse_method(method) if isinstance(method, str) else method
    sync = method.synchronous
    policy, goal_mode, needs = make_policy(method, setting.env_config(None, sync), seed, model)
    try:
        eng = EventEngine(setting.env_config(needs, sync), num_worlds=1, seed=seed, goal_mode=goal_mode)
        if plays_one_world_at_a_time(policy):
            policy.reset()
        fps = RENDER_FPS if fps is None else fps
        return render.render_episode(eng, policy, path, episode, fps=fps, max_frames=max_frames)
    finally:
        close_policy(policy)
