"""Who labels a decision: the teacher a DAgger round imitates, PPO's auxiliary labelers (the rescue rule,
an anchor planner)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from catmip_env.constants import TARGET_BIT
from catmip_env.engines.events import EventEngine
from catmip_env.planners.baselines import make_planner
from catmip_env.planners.core import Planner
from catmip_env.planners.window import WindowPlanner, make_window_planner
from catmip_rl.training.sections import LossSection

__all__ = ["RescueLabeler", "PlannerLabeler", "auxiliary_labeler", "make_teacher"]


def make_teacher(
    name: str, goals: str, seed: int = 0, follow_heading: bool = True
) -> Planner | WindowPlanner:
    """The teacher planner ``name`` for a model whose goals are ``goals`` (``AmatConfig.goals``): its goals
    projected into the goal window ("window"; ``follow_heading=False``: along a heading-free path, see
    :class:`~catmip_env.planners.window.WindowPlanner`), or the planner itself ("cell": the same action
    space, nothing projected)."""
    if goals == "window":
        return make_window_planner(name, seed=seed, follow_heading=follow_heading)
    return make_planner(name, seed=seed)


@dataclass
class RescueLabeler:
    """``act(engine)`` -> (B, N) labels for PPO's auxiliary rescue loss (``TrainConfig.rescue_coef``):
    the rescue rule's window action (the planners' shared rule, as ``teacher`` projects it:
    :func:`auxiliary_labeler` gives ``window:nearest``, or ``window-noheading:nearest``) for every active
    robot of a live world that can rescue and knows where the target is; -1 for every other robot. The
    teacher runs only on events where such a robot decides."""

    teacher: WindowPlanner

    def act(self, engine: EventEngine) -> np.ndarray:
        st = engine.state
        b, n = np.nonzero(engine.active & ~st.done[:, None] & st.can_rescue)
        knows = (st.belief[b, n, st.target[b, 0], st.target[b, 1]] & TARGET_BIT) != 0
        out = np.full(engine.active.shape, -1, np.int64)
        if knows.any():
            b, n = b[knows], n[knows]
            out[b, n] = self.teacher.act(engine)[b, n]
        return out


@dataclass
class PlannerLabeler:
    """``act(engine)`` -> (B, N) labels for PPO's anchor loss (``TrainConfig.anchor``): the planner's
    (``teacher``'s) own cell goal for every active robot of a live world, -1 for every other robot; with
    ``relay_only`` (``anchor_on="relay"``) only where the teacher's relay rule chose (``planners.Relay``)."""

    teacher: Planner
    relay_only: bool = False

    def act(self, engine: EventEngine) -> np.ndarray:
        out = np.asarray(self.teacher.act(engine), np.int64).copy()
        labelled = engine.active & ~engine.state.done[:, None]
        if self.relay_only:
            labelled &= self.teacher.relayed
        out[~labelled] = -1
        return out


def auxiliary_labeler(loss: LossSection, seed: int) -> RescueLabeler | PlannerLabeler | None:
    """The labeler of the auxiliary loss of a TrainConfig's ``loss`` section: the rescue rule as
    ``window:nearest`` projects it (``rescue_coef`` > 0; ``window-noheading:nearest`` without
    ``rescue_heading``), or the planner ``anchor`` itself (seeded by ``seed``, the run's); None without
    either."""
    if loss.rescue_coef > 0:
        return RescueLabeler(make_window_planner("nearest", follow_heading=loss.rescue_heading))
    if loss.anchor:
        return PlannerLabeler(make_planner(loss.anchor, seed=seed), relay_only=loss.anchor_on == "relay")
    return None
