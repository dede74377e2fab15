"""Episode statistics, in one place: what every evaluation, training log, demo and benchmark reports.

* :class:`EpisodeRecords` — one episode per world as plain arrays (ticks of the rescue, of the first
  sighting, of the first rescuer told; explored fraction; decisions and stalls per robot), read from an
  engine by :func:`episode_records`;
* :func:`episode_metrics` — the metrics of ``catmip eval``'s summary.json; :func:`success_curve` —
  rescued by tick t;
* :class:`DecisionTracker` / :func:`decision_metrics` — decisions and stalls;
* :func:`training_stats` — the training logs' columns (the same metrics, plus returns per class).

A **stall** is a macro-action that ended with its robot where it began, on the same cell with the same
heading: a "stay" goal, a goal the controller cannot reach, a goal that became occupied before the robot
left. (A macro-action that only turned the robot changed its view, so it is not counted.) Under
evaluation activation (0, 0) a deterministic policy that stalls decides again at once on an almost
unchanged observation, so stalls are what argmax loops look like. Counted at each robot's next
activation (a macro-action still running when the episode ends is not counted).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from catmip_env.config import EnvConfig
from catmip_env.engines.events import EventEngine

__all__ = [
    "EpisodeRecords",
    "episode_records",
    "success_curve",
    "episode_metrics",
    "decision_metrics",
    "DecisionTracker",
    "decision_summary",
    "training_stats",
]


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
    stalls: np.ndarray  # (B, N) int64 stalled macro-actions per robot (see DecisionTracker)
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


class DecisionTracker:
    """Decisions and stalls per (world, robot) over one episode of each world."""

    def __init__(self, num_worlds: int, num_robots: int) -> None:
        self.decisions = np.zeros((num_worlds, num_robots), np.int64)
        self.stalls = np.zeros((num_worlds, num_robots), np.int64)
        self._start = np.zeros((num_worlds, num_robots, 3), np.int64)  # row, col, heading

    def reset(self, engine: EventEngine, worlds: np.ndarray | None = None) -> None:
        """Zero the counts of ``worlds`` (default all) at the start of their episodes."""
        sel = slice(None) if worlds is None else worlds
        self.decisions[sel] = 0
        self.stalls[sel] = 0
        self._start[sel] = _pose(engine)[sel]

    def before_step(self, engine: EventEngine) -> None:
        """Count the decisions of this event and the stalls of the macro-actions they end."""
        st = engine.state
        act = engine.active & ~st.done[:, None]
        pose = _pose(engine)
        ended = act & (self.decisions > 0)
        self.stalls += ended & (pose == self._start).all(-1)
        self.decisions += act
        self._start[act] = pose[act]

    def summary(self, cls: np.ndarray, classes) -> dict[str, float]:
        """:func:`decision_summary` of the counts so far."""
        return decision_summary(self.decisions, self.stalls, cls, classes)


def decision_summary(decisions: np.ndarray, stalls: np.ndarray, cls: np.ndarray, classes) -> dict[str, float]:
    """Means per episode of (B, N) ``decisions`` and ``stalls`` of robots of class ``cls`` (B, N):
    ``decisions_per_episode``, ``stalls_per_episode`` and, per class name of ``classes``,
    ``stalls_per_episode_<name>`` and ``stall_fraction_<name>`` (stalls / completed macro-actions:
    every decision but each robot's last, which no later activation has ended)."""
    n_ep = max(decisions.shape[0], 1)
    out = {
        "decisions_per_episode": float(decisions.sum() / n_ep),
        "stalls_per_episode": float(stalls.sum() / n_ep),
    }
    for k, c in enumerate(classes):
        sel = cls == k
        ended = int((decisions[sel] - (decisions[sel] > 0)).sum())
        s = int(stalls[sel].sum())
        out[f"stalls_per_episode_{c.name}"] = s / n_ep
        out[f"stall_fraction_{c.name}"] = s / ended if ended else float("nan")
    return out


def _pose(engine: EventEngine) -> np.ndarray:
    """(B, N, 3) row, column and heading of every robot."""
    st = engine.state
    return np.concatenate([st.pos, st.heading[..., None].astype(st.pos.dtype)], -1)


def training_stats(records: EpisodeRecords, returns: np.ndarray, cfg: EnvConfig) -> dict[str, float]:
    """The training logs' episode statistics, under the names of the metrics every evaluation uses
    (:func:`episode_metrics`: ``success_rate``, ``success_by_100``, ``mean_rescue_tick``,
    ``mean_target_found_tick``, ... with NaN where a mean has no episode), plus ``mean_episode_ticks``,
    the mean episode return of each class (``return_<class>``) and the decisions and stalls per episode
    (``decision_metrics``)."""
    m = episode_metrics(records, cfg.horizon_ticks)
    m = {k: v for k, v in m.items() if k not in ("episodes", "horizon")}
    out = {k: float("nan") if v is None else float(v) for k, v in m.items()}
    out["mean_episode_ticks"] = float(records.ticks.mean())
    for k, cls in enumerate(cfg.classes):
        sel = records.cls == k
        out[f"return_{cls.name}"] = float(returns[sel].mean()) if sel.any() else float("nan")
    return out | decision_metrics(records, cfg.classes)
