"""A planner's proposal as one observation part: each deciding robot's goal cell by a named planner.

A model that reads a proposal (``AmatConfig.hint`` in ``catmip_rl``) gets it from here wherever it
plays or trains — the collector, the executor, the TorchRL env, a Ray worker — with one seeding rule:
the planner is seeded 0 and draws from its stream of each world's episode (:meth:`Planner.world_rng`),
so that every player of the same maps sees the same proposals.
"""

from __future__ import annotations

import numpy as np

from catmip_env.engines.events import EventEngine
from catmip_env.planners.baselines import make_planner

__all__ = ["NO_PROPOSAL", "Proposals"]

NO_PROPOSAL = -1  # the cell of a robot that does not decide now (busy, or its world is done)


class Proposals:
    """``proposals(engine)`` → (B, N) int64: the cell goal ``planner`` would give each active robot of a
    live world, from that robot's own view (the planner reads what the robot's neighbourhood knows),
    :data:`NO_PROPOSAL` elsewhere; ``planner`` "" (a model that reads none): :data:`NO_PROPOSAL`
    everywhere. Called once at each decision event, in order, as a player calls its policy: the planner
    keeps its per-world streams and any state between calls. ValueError for an unknown planner."""

    def __init__(self, planner: str = "") -> None:
        self.name = planner
        self.planner = make_planner(planner, seed=0) if planner else None

    def __call__(self, engine: EventEngine) -> np.ndarray:
        deciding = engine.active & ~engine.state.done[:, None]
        if self.planner is None:
            return np.full(deciding.shape, NO_PROPOSAL, np.int64)
        return np.where(deciding, np.asarray(self.planner.act(engine), np.int64), NO_PROPOSAL)
