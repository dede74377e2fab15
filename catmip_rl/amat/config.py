"""AMAT's hyper-parameters (:class:`AmatConfig`), apart from the model so that configs, presets and the
command line load without torch."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from typing import Any

from catmip_env.fields import BOOL, INT, check
from catmip_env.planners.baselines import PLANNERS

__all__ = ["AmatConfig", "GOAL_KINDS", "CELL_MASKS", "CRITICS"]

GOAL_KINDS = ("window", "cell")
CELL_MASKS = ("known", "reachable")
CRITICS = ("encoder", "state")
LIMITS = {
    "window": 99,
    "local_size": 99,
    "pool": 64,
    "embed_dim": 8192,
    "n_heads": 128,
    "n_blocks": 64,
    "n_classes": 64,
    "cell_channels": 4096,
    "cell_layers": 64,
}
"""The largest value of each size field (far above any trained model's)."""


@dataclass(frozen=True)
class AmatConfig:
    """Hyper-parameters of AMAT (defaults: the paper's Table 2)."""

    window: int = 7
    """D: side of the goal window; the policy has D*D actions."""
    local_size: int = 7
    """L: side of the robot-centred local map."""
    pool: int = 4
    """G: the global CNN's adaptive max-pool output side (any map size S works)."""
    embed_dim: int = 192
    """d: token width."""
    n_heads: int = 1
    """Attention heads (d must be divisible by it)."""
    n_blocks: int = 1
    """Encoder and decoder blocks."""
    n_classes: int = 2
    """C: robot classes (the class one-hot size)."""
    goals: str = "window"
    """"window": D*D goals around the robot (the paper's AMAT); "cell": any cell of the map, scored by a
    pointer head over per-cell features (``amat.pointer``, the planners' action space)."""
    cell_channels: int = 32
    """Goals "cell": width of the per-cell feature maps."""
    cell_mask: str = "known"
    """Goals "cell": the cells a robot may choose besides its own: "known" (explored and free on its map,
    reachable: where Nearest's and Utility's frontiers are) or "reachable" (any cell its map does not show
    occupied with a path to it, unknown cells included: where RRT sends robots)."""
    cell_layers: int = 4
    """Goals "cell": convolutions of the per-cell encoder: a 3x3, then residual 3x3s dilated 1, 1, 2, 4..."""
    teammate_memory: bool = False
    """Observes teammates outside its neighbourhood where it last had news of them (the env's
    ``EnvConfig.teammate_memory``; not the paper's observation): training worlds and evaluation turn
    the option on for such a model, and an engine without it is refused."""
    teammate_heading: bool = False
    """With ``teammate_memory``: sees each remembered teammate where it should be by now, moved toward the
    goal it was heading for (``EnvConfig.teammate_heading``)."""
    hint: str = ""
    """Goals "cell": a planner (``catmip_env.planners``, e.g. "rrt-relay-heading") whose goal for the deciding
    robot the model sees as one more per-cell input and a learned bonus on that cell's logit; "" none.
    Whoever plays the model runs that planner on the robot's own view at every decision (a proposal, not
    an order: the model points wherever it likes)."""
    critic: str = "encoder"
    """Where PPO's values come from: "encoder" (the paper's value head on the encoder's tokens) or
    "state" (``amat.critic.StateCritic``: a centralised critic that reads the world's true state beside
    the robot's own map, as MAPPO's does; training only, play never reads it)."""

    def __post_init__(self) -> None:
        for name, most in LIMITS.items():  # bounded: a file cannot declare a model too large to count
            odd = name in ("window", "local_size")
            rule = INT(
                f"{'that is odd and ' if odd else ''}from 1 to {most}",
                lambda v, most=most, odd=odd: 1 <= v <= most and (v % 2 or not odd),
            )
            check("AmatConfig", name, getattr(self, name), rule)
        if self.embed_dim % self.n_heads:
            raise ValueError(f"embed_dim {self.embed_dim} is not divisible by n_heads {self.n_heads}")
        if self.cell_mask not in CELL_MASKS:
            raise ValueError(
                f"AmatConfig.cell_mask must be one of {list(CELL_MASKS)}, got {self.cell_mask!r}"
            )
        check("AmatConfig", "teammate_memory", self.teammate_memory, BOOL)
        check("AmatConfig", "teammate_heading", self.teammate_heading, BOOL)
        if self.teammate_heading and not self.teammate_memory:
            raise ValueError(
                "AmatConfig.teammate_heading moves remembered teammates: set teammate_memory too"
            )
        if self.critic not in CRITICS:
            raise ValueError(f"AmatConfig.critic must be one of {list(CRITICS)}, got {self.critic!r}")
        if self.hint:
            if self.hint not in PLANNERS:
                raise ValueError(f"AmatConfig.hint must name a planner {sorted(PLANNERS)}, got {self.hint!r}")
            if self.goals != "cell":
                raise ValueError("AmatConfig.hint proposes a cell goal: set goals to 'cell' too")
        if self.goals not in GOAL_KINDS:
            raise ValueError(f"AmatConfig.goals must be one of {list(GOAL_KINDS)}, got {self.goals!r}")

    @property
    def num_actions(self) -> int:
        return self.window * self.window

    @property
    def global_channels(self) -> int:
        return 5 + self.n_classes

    @property
    def local_channels(self) -> int:
        return 4 + self.n_classes

    def env_overrides(self) -> dict[str, Any]:
        """What an env must set to give this model its observations and actions: the goal window (window
        goals), and the teammate memory (moved along their headings) when the model reads it."""
        needs = {"window": self.window} if self.goals == "window" else {}
        if self.teammate_memory:
            needs["teammate_memory"] = True
        if self.teammate_heading:
            needs["teammate_heading"] = True
        return needs

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2, sort_keys=True)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> AmatConfig:
        if not isinstance(data, dict):
            raise ValueError(f"AmatConfig fields must be a JSON object {{field: value}}, got {data!r}")
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"unknown AmatConfig field(s) {sorted(unknown)}")
        return cls(**data)
