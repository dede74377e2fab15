"""The episode loop and the episode metrics: every evaluation, demo, benchmark and render plays this.

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
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from catmip_env.decision_stats import DecisionTracker, decision_summary
from catmip_env.events import EventEngine

__all__ = [
    "Policy",
    "MESSAGE_COLUMNS",
    "plays_one_world_at_a_time",
    "episode_columns",
    "WorldNotSupported",
    "EpisodeRecords",
    "episode_records",
    "play",
    "success_curve",
    "episode_metrics",
    "decision_metrics",
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
      results' summary (``actions``).
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


@dataclass(frozen=True)
class EpisodeRecords:
    """One episode per world of a batch, as plain arrays (copies, not the engine's buffers).

    ``B`` worlds, ``N`` robots; a tick of -1 means "never" (not rescued, target never found)."""

    rescue_tick: np.ndarray  # (B,) int64 tick of the rescue, -1 if not rescued
    found_tick: np.ndarray  # (B,) int64 tick the target was first seen, -1 if never
    informed_tick: np.ndarray  # (B,) int64 tick a robot that can rescue first knew the target, -1 if never
    explored_fraction: np.ndarray  # (B,) float64 interior cells explored at the end, in [0, 1]
    ticks: np.ndarray  # (B,) int64 ticks the episode ran
    events: np.ndarray  # (B,) int64 decision events the world took part in
    decisions: np.ndarray  # (B, N) int64 decisions per robot
    stalls: np.ndarray  # (B, N) int64 stalled macro-actions per robot (see decision_stats)
    cls: np.ndarray  # (B, N) int64 class index of each robot

    @property
    def num_worlds(self) -> int:
        return len(self.rescue_tick)

    @classmethod
    def concat(cls, parts: list[EpisodeRecords]) -> EpisodeRecords:
        """The episodes of ``parts``, in order, as one record set."""
        names = cls.__dataclass_fields__
        return cls(**{k: np.concatenate([getattr(p, k) for p in parts]) for k in names})

    @property
    def rescued(self) -> np.ndarray:
        """(B,) bool: the episode ended in a rescue."""
        return self.rescue_tick >= 0

    @property
    def found(self) -> np.ndarray:
        """(B,) bool: a robot saw the target."""
        return self.found_tick >= 0


def episode_records(
    engine: EventEngine, tracker: DecisionTracker | None = None, events: np.ndarray | None = None
) -> EpisodeRecords:
    """The records of the engine's current episodes (read them once every world is done).

    ``tracker`` (reset at the episodes' start, ``before_step`` at every event) gives the decisions
    and stalls, ``events`` (B,) the event counts; without them those fields are zeros."""
    st = engine.state
    b, n = engine.num_worlds, engine.num_robots
    return EpisodeRecords(
        rescue_tick=st.rescue_tick.astype(np.int64),
        found_tick=st.found_tick.astype(np.int64),
        informed_tick=st.informed_tick.astype(np.int64),
        explored_fraction=np.asarray(engine.world.explored_fraction(), np.float64).copy(),
        ticks=st.ticks.astype(np.int64),
        events=np.zeros(b, np.int64) if events is None else np.array(events, np.int64),
        decisions=np.zeros((b, n), np.int64) if tracker is None else tracker.decisions.copy(),
        stalls=np.zeros((b, n), np.int64) if tracker is None else tracker.stalls.copy(),
        cls=st.cls.astype(np.int64),
    )


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


def success_curve(rescue_ticks: np.ndarray, horizon: int) -> np.ndarray:
    """Fraction of episodes rescued by tick t, for t = 0 .. horizon ((horizon + 1,) float64).

    ``rescue_ticks`` (B,): -1 for an episode without a rescue."""
    ticks = np.asarray(rescue_ticks)
    rescued = ticks[ticks >= 0]
    counts = np.bincount(np.minimum(rescued, horizon), minlength=horizon + 1)
    return np.cumsum(counts) / max(len(ticks), 1)


def _mean_or_none(values: np.ndarray) -> float | None:
    return float(values.mean()) if len(values) else None


def episode_metrics(records: EpisodeRecords, horizon: int) -> dict[str, Any]:
    """The episode metrics of ``records`` (``horizon``: the episodes' ``horizon_ticks``).

    ``episodes``; ``horizon``; ``success_rate`` (rescued by the horizon) and ``success_by_100``
    (rescued by tick 100 or the horizon if shorter), the ends of :func:`success_curve`;
    ``mean_rescue_tick`` / ``mean_target_found_tick`` over the episodes with a rescue / a sighting
    (None if there is none); ``target_found_rate``; ``mean_found_to_informed_ticks`` (from the first
    sighting to the first tick a robot that can rescue knows the target: how long the news travels) and
    ``mean_informed_to_rescue_ticks`` (from then to the rescue), over the episodes where each happened;
    ``mean_explored_fraction``; ``decisions`` (robot decisions in all episodes). These are the keys and
    values of ``catmip eval``'s summary.json."""
    curve = success_curve(records.rescue_tick, horizon)
    informed = records.informed_tick >= 0
    return {
        "episodes": records.num_worlds,
        "horizon": horizon,
        "success_rate": float(curve[-1]),
        "success_by_100": float(curve[min(100, horizon)]),
        "mean_rescue_tick": _mean_or_none(records.rescue_tick[records.rescued]),
        "mean_target_found_tick": _mean_or_none(records.found_tick[records.found]),
        "target_found_rate": float(records.found.mean()),
        "mean_found_to_informed_ticks": _mean_or_none((records.informed_tick - records.found_tick)[informed]),
        "mean_informed_to_rescue_ticks": _mean_or_none(
            (records.rescue_tick - records.informed_tick)[records.rescued & informed]
        ),
        "mean_explored_fraction": float(records.explored_fraction.mean()),
        "decisions": int(records.decisions.sum()),
    }


def decision_metrics(records: EpisodeRecords, classes) -> dict[str, float]:
    """Decisions and stalls per episode, and per robot class (``classes``: ``cfg.classes``): the
    keys of :meth:`DecisionTracker.summary`."""
    return decision_summary(records.decisions, records.stalls, records.cls, classes)
