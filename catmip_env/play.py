"""The episode loop: every evaluation, demo, benchmark and render plays this (what it returns is
measured by :mod:`catmip_env.engines.episode_stats`).

>>> eng = EventEngine(cfg, num_worlds=100, seed=0, goal_mode="cell")
>>> eng.reset(episode_indices=np.arange(100))   # the caller picks the maps
>>> records = play(eng, make_planner("nearest"))  # each world to the end of its episode
>>> episode_metrics(records, cfg.horizon_ticks)   # success_rate, success_by_100, mean ticks ...
>>> success_curve(records.rescue_tick, cfg.horizon_ticks)  # rescued by tick t, t = 0 .. horizon

A policy is anything with ``act(engine) -> (B, N) int`` goal actions (a planner, a window planner,
``catmip_rl``'s ``AmatExecutor``) or such a function. Only the active robots of live worlds are read.
Worlds whose episode ended are frozen by the engine, so what :func:`episode_records` reads at the end
of the loop is what each world held when its episode ended.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from catmip_env.engines.episode_stats import DecisionTracker, EpisodeRecords, episode_records
from catmip_env.engines.events import EventEngine

__all__ = [
    "Policy",
    "MESSAGE_COLUMNS",
    "plays_one_world_at_a_time",
    "episode_columns",
    "WorldNotSupported",
    "play",
]


class Policy(Protocol):
    """Goal actions for the current event of every world of an engine.

    ``act`` is all a policy needs. An evaluator (``catmip_rl.evaluation.evaluate``) also asks for these
    optional members, for a user's policy as for AMAT, and never checks a policy's class:

    * ``start_episodes(num_worlds, num_robots)``: called before a batch of maps is played (counters, memory);
    * ``episode_columns() -> {name: values}``: extra per-episode columns of the results, one value per
      episode in the order played (AMAT: its decision ``messages``, ``bytes_embedding``, ``bytes_raw``;
      a policy without it sends none: :data:`MESSAGE_COLUMNS` are zeros, as for the planners, which decide
      on their robot's own merged map);
    * ``sampled(seed) -> Policy``: the same policy with sampled actions (seeded by ``seed``); the evaluator
      plays the maps again with it and reports ``sampled_*`` beside the policy's own (argmax) numbers;
    * ``one_world_at_a_time = True``: play the maps one after another on a one-world engine, calling
      ``reset()`` before each (a PettingZoo-level policy with memory);
    * ``deterministic: bool``: whether ``act`` plays argmax (True) or samples (False), written on the
      results' summary (``actions``);
    * ``files``: paths of the files its answers depend on (its weights), each written on the results'
      summary with its SHA-256 (``policy_files``): a resumed evaluation refuses results played before one
      of them changed.
    """

    def act(self, engine: EventEngine) -> np.ndarray:  # (B, N) int goal actions
        ...


MESSAGE_COLUMNS = ("messages", "bytes_embedding", "bytes_raw")
"""Per-episode decision traffic: messages sent, their bytes with embeddings, with raw observations."""


def plays_one_world_at_a_time(policy: Any) -> bool:
    """Whether ``policy`` asks to play its maps one after another (:class:`Policy`)."""
    return bool(getattr(policy, "one_world_at_a_time", False))


def episode_columns(policy: Any, num_episodes: int) -> dict[str, np.ndarray]:
    """The policy's extra per-episode columns (:class:`Policy`), :data:`MESSAGE_COLUMNS` zero unless it
    reports them; ValueError naming a column that is not ``num_episodes`` numbers."""
    columns = {name: np.zeros(num_episodes, np.int64) for name in MESSAGE_COLUMNS}
    report = getattr(policy, "episode_columns", None)
    if report is None:
        return columns
    reported = report()
    if not isinstance(reported, dict):
        raise ValueError(f"episode_columns() returned {type(reported).__name__}, expected {{name: values}}")
    for name, values in reported.items():
        values = np.asarray(values)
        if not isinstance(name, str) or not name.isidentifier():
            raise ValueError(f"episode_columns(): column name {name!r} is not an identifier")
        if values.shape != (num_episodes,) or values.dtype.kind not in "biuf":
            raise ValueError(
                f"episode_columns(): column {name!r} holds {values.dtype} values of shape {values.shape}, "
                f"expected {num_episodes} numbers (one per episode)"
            )
        columns[name] = values
    return columns


class WorldNotSupported(ValueError):
    """Raised by a policy (or its factory) built for other worlds than the one it is asked to play: e.g.
    a network whose input size is one map size. ``catmip bench paper`` then leaves that method out of
    that panel and says so; a single evaluation (``catmip eval``) reports it as an error."""


def play(
    engine: EventEngine,
    policy: Policy | Callable[[EventEngine], np.ndarray],
    on_event: Callable[[EventEngine], Any] | None = None,
    until: Callable[[EventEngine], bool] | None = None,
    max_ticks: int | None = None,
) -> EpisodeRecords:
    """Play the episodes ``engine`` was reset to until every world is done; their records.

    At every event: ``policy.act(engine)`` (or ``policy(engine)``) chooses the goals, the engine
    steps to the next event, then ``on_event(engine)`` runs (progress bars, frames, inspection).
    ``until(engine)``, checked before every event, stops the loop early (the records are then of
    unfinished episodes). ``max_ticks`` is passed to :meth:`EventEngine.step` (1: a pause after
    every tick, for rendering)."""
    act = policy.act if hasattr(policy, "act") else policy
    tracker = DecisionTracker(engine.num_worlds, engine.num_robots)
    tracker.reset(engine)
    events = np.zeros(engine.num_worlds, np.int64)
    while not engine.state.done.all():
        if until is not None and until(engine):
            break
        events += ~engine.state.done
        tracker.before_step(engine)
        engine.step(act(engine), max_ticks=max_ticks)
        if on_event is not None:
            on_event(engine)
    return episode_records(engine, tracker, events)
