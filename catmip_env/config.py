"""Configuration of the search-and-rescue world: robot classes, the env config, and presets.

Everything that defines a task lives in one frozen :class:`EnvConfig`; presets are plain instances in
:data:`PRESETS`. ``EnvConfig.replace(**overrides)`` (or :func:`make_config`) applies validated overrides by
field name, which is how the PettingZoo factory and the CLIs take their flags.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NoReturn

from catmip_env.fields import BOOL, INT, NUMBER, STR, Rule, check, is_int, is_number, is_str

__all__ = [
    "EnvConfig",
    "RobotClass",
    "PRESETS",
    "EXPLORER",
    "RESCUER",
    "make_config",
    "MAX_MAP_SIZE",
    "MAX_TICKS",
    "MIN_COMM_SIGMA",
]

#: Spawn box side: robots start on free cells of the 4x4 box just inside a map corner.
SPAWN_BOX = 4
#: The target is never placed inside this box at the robots' corner.
TARGET_EXCLUSION_BOX = 8
#: Side of the square sensor window (own row plus ``VIEW_SIZE - 1`` rows ahead).
VIEW_SIZE = 7
#: Largest generated map side: beliefs, observations and planner buffers grow as S^2 per robot and
#: world (a 512 x 512 world's observations are ~2 MB per robot), so larger maps only exhaust memory.
MAX_MAP_SIZE = 512
#: Longest episode and macro-action in ticks (a paper task's horizon is 300 to 500 ticks): a run's curve
#: holds a value per tick, and a count past int64 fails inside the compiled kernels, not in one line.
MAX_TICKS = 1_000_000
#: Smallest communication range sigma (cells). Robots stand >= 1 cell apart, so below ~0.037 a link's
#: probability exp(-d^2/sigma^2) is exactly 0.0 in float64 anyway; a tinier sigma only breaks the maths
#: (1/sigma^2 overflows below ~1e-154, and sigma^2 is 0.0 below ~1e-162: a ZeroDivisionError in the kernels).
MIN_COMM_SIGMA = 0.01


def _is_comm_range(v: Any) -> bool:
    """A communication range: None (full communication) or a finite number >= MIN_COMM_SIGMA."""
    return v is None or (is_number(v) and v >= MIN_COMM_SIGMA)


# the fields that hold lists: stored as tuples (hashable, immutable), whatever list they were given as
_LISTS = ("team", "random_classes", "activation", "classes", "comm_sigma_choices")


@dataclass(frozen=True)
class RobotClass:
    """A kind of robot. Classes are data: any number of them may be defined."""

    name: str
    """Unique class name (used in configs, logs and rendering)."""
    ticks_per_action: int = 1
    """Speed: the robot executes one primitive action every this many ticks."""
    can_rescue: bool = False
    """Whether this class completes the mission by standing next to the known target."""

    def __post_init__(self) -> None:
        check("RobotClass", "name", self.name, STR("(not empty)", bool))
        owner = f"RobotClass({self.name!r})"
        check(owner, "ticks_per_action", self.ticks_per_action, INT(">= 1", lambda v: v >= 1))
        check(owner, "can_rescue", self.can_rescue, BOOL)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RobotClass:
        """A class from ``{"name": ..., "ticks_per_action": ..., "can_rescue": ...}`` (JSON configs)."""
        if not isinstance(data, dict):
            raise ValueError(
                f"a robot class must be a RobotClass or a JSON object of its fields, got {data!r}"
            )
        unknown = sorted(set(data) - {f.name for f in dataclasses.fields(cls)})
        if unknown or "name" not in data:
            raise ValueError(
                f"robot class {data!r}: fields are name (required), ticks_per_action, can_rescue"
                + (f"; unknown: {unknown}" if unknown else "")
            )
        return cls(**data)


EXPLORER = RobotClass("explorer", ticks_per_action=1, can_rescue=False)
RESCUER = RobotClass("rescuer", ticks_per_action=2, can_rescue=True)


@dataclass(frozen=True)
class EnvConfig:
    """One task of the search-and-rescue world (docs/design.md#world-rules). Frozen, validated on creation."""

    map_size: int = 20
    """Side S of the square generated map, outer wall ring included (10 <= S <= MAX_MAP_SIZE = 512)."""
    team: tuple[str, ...] = ("rescuer", "explorer", "explorer")
    """Class name of each robot ``robot_i``; the entry ``"random"`` draws a class per episode."""
    random_classes: tuple[str, ...] = ("rescuer", "explorer")
    """Classes a ``"random"`` team slot is drawn from (uniformly, from the episode's map stream)."""
    classes: tuple[RobotClass, ...] = (RESCUER, EXPLORER)
    """All robot classes; their order fixes the class one-hot and the per-class observation channels."""
    horizon_ticks: int = 200
    """Episode length h in ticks; the episode is truncated for everyone after tick h."""
    num_obstacles: int | None = None
    """Single-cell obstacles per map; ``None`` means floor(S^2 / 40)."""
    wall_prob: float = 0.9
    """Probability that a wall segment (with one doorway) separates two adjacent rooms."""
    comm_sigma: float | None = None
    """Communication range sigma in cells (>= MIN_COMM_SIGMA = 0.01); ``None`` is full communication. Link
    prob exp(-d^2/sigma^2)."""
    comm_sigma_choices: tuple[float | None, ...] = ()
    """If not empty, each episode draws its communication range uniformly from these (``None``: full
    communication), from the episode's map stream after its map, and ``comm_sigma`` is not used: one
    policy trained across ranges. Empty (default): every episode uses ``comm_sigma``."""
    slam_noise: float = 0.0
    """Per-tick probability that each explored cell of a robot's used occupancy map is flipped."""
    teammate_memory: bool = False
    """Observation option: the global map also shows each teammate outside the robot's neighbourhood where
    the robot last had news of it (0.5; 0.25 if it did not know the target the robot knows). The paper's
    observation is without it; the memory itself is always kept in the state (``heard_*``)."""
    teammate_heading: bool = False
    """With ``teammate_memory``: show each remembered teammate where it should be by now rather than where it
    was, moved from there toward the goal it was heading for at its speed (``comms.estimated_cells``; the
    goal travels with the news, ``heard_goal``)."""
    local_size: int = 7
    """Side L of the robot-centred local map (odd)."""
    window: int = 7
    """Side D of the goal window of the macro level (odd); D^2 window actions."""
    step_reward: float = -0.05
    """Reward for every successful forward move (energy)."""
    collision_penalty: float = 0.0
    """Reward added when a forward move hits a wall, an obstacle or the target."""
    find_reward: float = 100.0
    """Team reward scale when the target first becomes known: find_reward * (1 - 0.9 t/h)."""
    rescue_reward: float = 300.0
    """Team reward scale on success: rescue_reward * (1 - 0.9 t/h)."""
    layout: str | None = None
    """Optional fixed ASCII map (see :mod:`catmip_env.ascii_maps`); replaces map generation."""
    max_ma_ticks: int = 10
    """Macro level: a macro-action ends after this many ticks (the paper studies 5 / 10 / 20)."""
    activation: tuple[int, int] = (2, 5)
    """Macro level: (t_min, t_max) waiting ticks of asynchronous activation; (0, 0) decides at once."""
    synchronous: bool = False
    """Macro level: every robot decides together every ``max_ma_ticks`` ticks (Synch-CATMiP)."""

    # -- derived -------------------------------------------------------------------------------
    def __post_init__(self) -> None:
        for name in _LISTS:  # JSON lists become tuples; anything else is left for _validate to name
            if isinstance(getattr(self, name), list):
                object.__setattr__(self, name, tuple(getattr(self, name)))
        _validate(self)

    @property
    def comm_ranges(self) -> tuple[float | None, ...]:
        """The communication ranges episodes are drawn from: ``comm_sigma_choices``, or ``(comm_sigma,)``."""
        return tuple(self.comm_sigma_choices) or (self.comm_sigma,)

    @property
    def num_robots(self) -> int:
        return len(self.team)

    @property
    def num_classes(self) -> int:
        return len(self.classes)

    @property
    def obstacles(self) -> int:
        """Number of obstacles actually placed on a generated map."""
        if self.num_obstacles is not None:
            return self.num_obstacles
        return self.map_size**2 // 40

    @property
    def map_shape(self) -> tuple[int, int]:
        """(rows, cols) of the world grid: the layout's shape, or (S, S)."""
        if self.layout is not None:
            from catmip_env.ascii_maps import parse_layout

            return parse_layout(self.layout).grid.shape
        return (self.map_size, self.map_size)

    def class_index(self, name: str) -> int:
        for i, c in enumerate(self.classes):
            if c.name == name:
                return i
        raise ValueError(f"unknown robot class {name!r}; known: {[c.name for c in self.classes]}")

    def replace(self, **overrides: Any) -> EnvConfig:
        """A copy with fields replaced by name (unknown names raise ``ValueError``)."""
        names = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(overrides) - names)
        if unknown:
            raise ValueError(f"unknown EnvConfig field(s) {unknown}; valid fields: {sorted(names)}")
        if isinstance(overrides.get("classes"), (list, tuple)):  # JSON objects -> RobotClass
            try:
                overrides["classes"] = tuple(
                    c if isinstance(c, RobotClass) else RobotClass.from_dict(c) for c in overrides["classes"]
                )
            except ValueError as err:
                raise ValueError(f"EnvConfig: classes: {err}") from None
        return dataclasses.replace(self, **overrides)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=True)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> EnvConfig:
        if not isinstance(data, dict):
            raise ValueError(f"EnvConfig fields must be a JSON object {{field: value}}, got {data!r}")
        return cls().replace(**data)


def _list_of(item: Callable[[Any], bool], length: int | None = None) -> Callable[[Any], bool]:
    return lambda v: isinstance(v, (list, tuple)) and length in (None, len(v)) and all(map(item, v))


def _odd(v: int) -> bool:
    return v >= 1 and v % 2 == 1


def _probability(v: float) -> bool:
    return 0.0 <= v <= 1.0


# every field's type and range (catmip_env.fields); the checks across fields are in _validate
_RULES: dict[str, Rule] = {
    "map_size": INT(f"in [10, {MAX_MAP_SIZE}]", lambda v: 10 <= v <= MAX_MAP_SIZE),
    "team": Rule("a list of class names", _list_of(is_str)),
    "random_classes": Rule("a list of class names", _list_of(is_str)),
    "classes": Rule("a list of robot classes", _list_of(lambda c: isinstance(c, RobotClass))),
    "horizon_ticks": INT(f"in [1, {MAX_TICKS}]", lambda v: 1 <= v <= MAX_TICKS),
    "num_obstacles": Rule(
        "None or an int", lambda v: v is None or is_int(v), ">= 0", lambda v: v is None or v >= 0
    ),
    "wall_prob": NUMBER("in [0, 1]", _probability),
    "comm_sigma": Rule(
        "None (full communication) or a finite number",
        lambda v: v is None or is_number(v),
        f">= {MIN_COMM_SIGMA} (cells)",
        _is_comm_range,
    ),
    "comm_sigma_choices": Rule(
        f"a list of finite numbers >= {MIN_COMM_SIGMA} (cells) or null (full communication)",
        _list_of(_is_comm_range),
    ),
    "slam_noise": NUMBER("in [0, 1]", _probability),
    "teammate_memory": BOOL,
    "teammate_heading": BOOL,
    "local_size": INT("that is odd and >= 1", _odd),
    "window": INT("that is odd and >= 1", _odd),
    "step_reward": NUMBER,
    "collision_penalty": NUMBER,
    "find_reward": NUMBER(">= 0", lambda v: v >= 0),
    "rescue_reward": NUMBER(">= 0", lambda v: v >= 0),
    "max_ma_ticks": INT(f"in [1, {MAX_TICKS}]", lambda v: 1 <= v <= MAX_TICKS),
    "synchronous": BOOL,
    "activation": Rule(
        "a list of two ints",
        _list_of(is_int, 2),
        "[t_min, t_max] with 0 <= t_min <= t_max",
        lambda a: 0 <= a[0] <= a[1],
    ),
    "layout": Rule(
        "None or one string holding the ASCII map (rows separated by newlines)",
        lambda v: v is None or isinstance(v, str),
    ),
}


def _validate(cfg: EnvConfig) -> None:
    """Every field's rule, then the checks across fields; ValueError naming the first problem."""
    for f in dataclasses.fields(cfg):
        check("EnvConfig", f.name, getattr(cfg, f.name), _RULES[f.name])
    _validate_team(cfg)
    _validate_world(cfg)


def _fail(msg: str) -> NoReturn:
    raise ValueError(f"EnvConfig: {msg}")


def _validate_team(cfg: EnvConfig) -> None:
    """The classes have unique names, and the team's slots (and random_classes) name them."""
    if not cfg.classes:
        _fail("classes must name at least one RobotClass")
    names = [c.name for c in cfg.classes]
    if len(set(names)) != len(names):
        _fail(f"class names must be unique, got {names}")
    if "random" in names:
        _fail("'random' is reserved for team slots and cannot be a class name")
    if not cfg.team:
        _fail("team must contain at least one robot")
    for slot in cfg.team:
        if slot != "random" and slot not in names:
            _fail(f"unknown class name {slot!r} in team; known classes: {names} (or 'random')")
    if "random" in cfg.team:
        if not cfg.random_classes:
            _fail("random_classes must not be empty when the team has a 'random' slot")
        for name in cfg.random_classes:
            if name not in names:
                _fail(f"unknown class name {name!r} in random_classes; known classes: {names}")


def _validate_world(cfg: EnvConfig) -> None:
    """The team fits the map (spawn box or layout), the obstacles fit the map, one way to set the range."""
    if cfg.layout is None and cfg.num_robots > SPAWN_BOX * SPAWN_BOX:
        _fail(
            f"{cfg.num_robots} robots do not fit the {SPAWN_BOX}x{SPAWN_BOX} spawn box "
            f"({SPAWN_BOX * SPAWN_BOX} cells)"
        )
    if cfg.comm_sigma is not None and cfg.comm_sigma_choices:
        _fail(
            f"give comm_sigma ({cfg.comm_sigma!r}) or comm_sigma_choices ({cfg.comm_sigma_choices!r}), not "
            "both: with choices every episode draws its range from them"
        )
    if cfg.teammate_heading and not cfg.teammate_memory:
        _fail("teammate_heading moves the remembered teammates of teammate_memory: set teammate_memory too")
    if cfg.layout is None and cfg.obstacles > (cfg.map_size - 2) ** 2 // 4:
        _fail(f"num_obstacles={cfg.obstacles} is too many for a {cfg.map_size}x{cfg.map_size} map")
    if cfg.layout is not None:
        from catmip_env.ascii_maps import parse_layout

        lay = parse_layout(cfg.layout)
        if lay.num_robots != cfg.num_robots:
            _fail(f"layout places {lay.num_robots} robots but team has {cfg.num_robots}")


def make_config(preset: str | EnvConfig = "task2", **overrides: Any) -> EnvConfig:
    """Resolve a preset name (or config) and apply overrides by ``EnvConfig`` field name."""
    if isinstance(preset, EnvConfig):
        base = preset
    else:
        if preset not in PRESETS:
            raise ValueError(f"unknown preset {preset!r}; known presets: {sorted(PRESETS)}")
        base = PRESETS[preset]
    return base.replace(**overrides) if overrides else base


PRESETS: dict[str, EnvConfig] = {
    # Evaluation tasks (paper Section 7): horizons 300 / 400 / 500 ticks, robots decide at once.
    "task1": EnvConfig(map_size=15, team=("rescuer", "explorer"), horizon_ticks=300, activation=(0, 0)),
    "task2": EnvConfig(
        map_size=20, team=("rescuer", "explorer", "explorer"), horizon_ticks=400, activation=(0, 0)
    ),
    "task3": EnvConfig(
        map_size=32,
        team=("rescuer", "rescuer", "explorer", "explorer", "explorer", "explorer"),
        horizon_ticks=500,
        activation=(0, 0),
    ),
    # Training (paper Section 6): rescuer + explorer + one robot of random class, horizon 200,
    # asynchronous activation (2, 5), macro-actions of at most 10 ticks.
    "train": EnvConfig(map_size=20, team=("rescuer", "explorer", "random"), horizon_ticks=200),
}
