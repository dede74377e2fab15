"""Per-episode decision statistics shared by training logs and evaluation summaries.

A **stall** is a macro-action that ended with its robot where it began, on the same cell with the same
heading: a "stay" goal, a goal the controller cannot reach, a goal that became occupied before the robot
left. (A macro-action that only turned the robot changed its view, so it is not counted.) Under
evaluation activation (0, 0) a deterministic policy that stalls decides again at once on an almost
unchanged observation, so stalls are what argmax loops look like. Counted at each robot's next
activation (a macro-action still running when the episode ends is not counted).

>>> tracker = DecisionTracker(engine.num_worlds, engine.num_robots)
>>> tracker.reset(engine)              # after engine.reset()
>>> tracker.before_step(engine)        # at every event, before engine.step(...)
>>> tracker.summary(engine.state.cls, engine.cfg.classes)
"""

from __future__ import annotations

import numpy as np

from catmip_env.events import EventEngine

__all__ = ["DecisionTracker", "decision_summary"]


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
