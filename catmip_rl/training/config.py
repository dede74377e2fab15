"""Training configuration: TrainConfig, one frozen dataclass in sections (``training.sections``: env, model,
collection, loss, optim, imitation, eval) beside the run's own fields (seed, device, threads,
checkpoint_every), validated when built, saved as JSON in every run dir (its presets:
catmip_rl.training.presets).

Code reads a field through its section (``cfg.optim.lr``), so that a part that needs the optimiser's
settings gets ``cfg.optim``, not the whole config. A person names a field by its own name, unique across
the sections: the flags (``--lr``), ``--set lr=...``, :meth:`TrainConfig.replace` (``replace(lr=...)``, or
a section: ``replace(optim={"lr": ...})``) and the JSON.

``config.json`` stays flat (``{"lr": 0.0001, ...}``), as every run before the sections wrote it: its keys
are the flags' and ``--set``'s names, a saved config reads the same whatever the code's grouping, and what
reads a field from the raw JSON keeps reading it (``store.checkpoint``: a checkpoint's ``env_overrides``,
``seed`` and ``precision``; a model file's ``train_config``; older catmip versions).
:meth:`TrainConfig.from_json` reads the sectioned form too (``{"optim": {"lr": 0.0001, ...}, "seed": 0}``).
"""

from __future__ import annotations

import ast
import dataclasses
import json
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

from catmip_env import EnvConfig, make_config
from catmip_env.fields import BOOL, INT, NUMBER, STR, Rule, check, is_str
from catmip_env.planners.baselines import PLANNERS, Relay
from catmip_rl.amat.config import AmatConfig
from catmip_rl.training import sections
from catmip_rl.training.sections import (
    SECTIONS,
    CollectionSection,
    EnvSection,
    EvalSection,
    ImitationSection,
    LossSection,
    ModelSection,
    OptimSection,
)

__all__ = ["TrainConfig", "check_field", "field_docs", "field_types"]


# what each annotated type admits (annotations are strings: from __future__ import annotations)
_TYPES: dict[str, Rule] = {
    "int": INT,
    "float": NUMBER,
    "str": STR,
    "bool": BOOL,
    "str | None": Rule("a string or null", lambda v: v is None or is_str(v)),
    "dict[str, Any]": Rule("a JSON object {field: value}", lambda v: isinstance(v, dict)),
    "list[dict[str, Any]]": Rule(
        "a JSON list of objects [{field: value}, ...]",
        lambda v: isinstance(v, list) and all(isinstance(x, dict) for x in v),
    ),
}
PRECISIONS = ("fp32", "bf16", "auto")  # TrainConfig.precision (training.ppo resolves it)
# the planners with a relay rule (planners.Relay): anchor_on "relay" and warm_start_relay need one
RELAY_PLANNERS = sorted(name for name, planner in PLANNERS.items() if issubclass(planner, Relay))
# and each numeric field's range (seeds: torch's generators take 64-bit seeds)
_RANGES: dict[str, tuple[str, Callable[[Any], bool]]] = {
    **dict.fromkeys(
        (
            "num_worlds",
            "iterations",
            "epochs",
            "minibatches",
            "threads",
            "update_processes",
            "eval_episodes",
            "warm_start_rounds",
            "warm_start_steps",
            "warm_start_batch",
            "ray_workers",
        ),
        (">= 1", lambda v: v >= 1),
    ),
    "warm_start_worlds": (">= 0", lambda v: v >= 0),
    **dict.fromkeys(
        (
            "micro_batch",
            "eval_every",
            "checkpoint_every",
            "value_warmup_iterations",
            "budget_minutes",
            "target_kl",
            "entropy_coef",
            "value_coef",
            "rescue_coef",
            "anchor_coef",
            "critic_lr",
            "warm_start_relay",
        ),
        (">= 0", lambda v: v >= 0),
    ),
    **dict.fromkeys(
        ("lr", "adam_eps", "clip", "value_clip", "huber_delta", "max_grad_norm", "warm_start_lr"),
        ("> 0", lambda v: v > 0),
    ),
    **dict.fromkeys(("seed", "eval_seed"), (">= 0 and < 2**64", lambda v: 0 <= v < 2**64)),
    "gamma": ("in (0, 1]", lambda v: 0 < v <= 1),
    "lam": ("in [0, 1]", lambda v: 0 <= v <= 1),
}
# and the string fields that take a few values only
_VALUES: dict[str, Rule] = {
    "device": Rule("cpu, cuda or cuda:N", lambda v: is_str(v) and re.fullmatch(r"cpu|cuda(:\d+)?", v)),
    "precision": Rule(", ".join(PRECISIONS[:-1]) + " or " + PRECISIONS[-1], lambda v: v in PRECISIONS),
    "collector": Rule("local or ray", lambda v: v in ("local", "ray")),
    "warm_start": Rule(f"'' or a planner name {sorted(PLANNERS)}", lambda v: v == "" or v in PLANNERS),
    "anchor": Rule(f"'' or a planner name {sorted(PLANNERS)}", lambda v: v == "" or v in PLANNERS),
    "anchor_on": Rule("every or relay", lambda v: v in ("every", "relay")),
    "ray_address": Rule(
        "None, 'auto', 'host:port' or 'ray://host:port'", lambda v: v is None or (is_str(v) and v != "")
    ),
}


@cache
def _fields() -> dict[str, tuple[str, dataclasses.Field]]:
    """Every field by its flat name: (the name of its section, "" for TrainConfig's own; the field)."""
    out = {}
    for f in dataclasses.fields(TrainConfig):
        if f.name in SECTIONS:
            out |= {g.name: (f.name, g) for g in dataclasses.fields(SECTIONS[f.name])}
        else:
            out[f.name] = ("", f)
    return out


def field_types() -> dict[str, str]:
    """Each field's annotated type (a string: "int", "str | None", ...) by its flat name."""
    return {name: f.type for name, (_, f) in _fields().items()}


@cache
def _rules() -> dict[str, Rule]:
    """Every field's rule (catmip_env.fields): its type, range or values."""
    out = {}
    for name, kind in field_types().items():
        rule = _VALUES.get(name) or _TYPES[kind]
        out[name] = rule(*_RANGES[name]) if name in _RANGES else rule
    return out


def check_field(name: str, value: Any) -> None:
    """A ValueError naming the field unless ``value`` is of the field's annotated type (an int field a
    real int, never a bool; a float field a finite number) and in its range or values: "TrainConfig.
    eval_seed must be an int >= 0 and < 2**64, got 1.5". The one check of a field's value, for the
    config and for ``catmip train``'s flags (the same validator as EnvConfig's: catmip_env.fields).
    Fields go by their flat names, in every section."""
    check("TrainConfig", name, value, _rules()[name])


@cache
def field_docs() -> dict[str, str]:
    """Each documented field's docstring (the string under it in its section's class, or in TrainConfig's),
    whitespace collapsed, by its flat name: the help of ``catmip train``'s flags."""
    docs = {}
    for path, classes in ((sections.__file__, SECTIONS.values()), (__file__, [TrainConfig])):
        names = {c.__name__ for c in classes}
        tree = ast.parse(Path(path).read_text())
        for node in tree.body:
            if isinstance(node, ast.ClassDef) and node.name in names:
                docs |= _docstrings(node.body)
    return {name: doc for name, doc in docs.items() if name in _fields()}


def _docstrings(body: list[ast.stmt]) -> dict[str, str]:
    """The docstring under each annotated name of a class body, whitespace collapsed."""
    docs = {}
    for node, after in zip(body, body[1:]):
        documented = isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant)
        if isinstance(node, ast.AnnAssign) and documented:
            docs[node.target.id] = " ".join(str(after.value.value).split())
    return docs


@dataclass(frozen=True, init=False)
class TrainConfig:
    """The paper's recipe (docs/design.md#ppo-recipe) by default: its sections (``training.sections``),
    then the run's own fields."""

    env: EnvSection = field(default_factory=EnvSection)
    model: ModelSection = field(default_factory=ModelSection)
    collection: CollectionSection = field(default_factory=CollectionSection)
    loss: LossSection = field(default_factory=LossSection)
    optim: OptimSection = field(default_factory=OptimSection)
    imitation: ImitationSection = field(default_factory=ImitationSection)
    eval: EvalSection = field(default_factory=EvalSection)
    seed: int = 0
    """Seed of the training worlds, the initial weights and the sampling."""
    device: str = "cpu"
    """Where the model trains: cpu, cuda or cuda:N."""
    threads: int = 2
    """torch CPU threads."""
    checkpoint_every: int = 50
    """Iterations between checkpoints, and one at the end (0 = none: the run cannot be resumed)."""

    def __init__(self, **fields: Any) -> None:
        """Fields by their flat names (``TrainConfig(lr=3e-4)``, as the flags and :meth:`replace` name them),
        or sections by name (``optim=OptimSection(...)``); the rest the paper's recipe."""
        own = [f.name for f in dataclasses.fields(TrainConfig)]
        if not set(fields) <= set(own) or any(isinstance(fields.get(name), dict) for name in SECTIONS):
            built = TrainConfig().replace(**fields)  # flat names: sorted into their sections
            fields = {name: getattr(built, name) for name in own}
        for f in dataclasses.fields(TrainConfig):
            default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
            object.__setattr__(self, f.name, fields.get(f.name, default))
        self.__post_init__()

    def __post_init__(self) -> None:
        for name, kind in SECTIONS.items():
            if not isinstance(getattr(self, name), kind):
                raise ValueError(
                    f"TrainConfig.{name} must be its section ({kind.__name__}), got {getattr(self, name)!r}"
                )
        for name, value in self.to_dict().items():
            check_field(name, value)
        amat = self.amat_config()  # validates it
        self._check_losses(amat)
        if self.optim.update_processes > 1 and self.device != "cpu":
            raise ValueError(
                f"update_processes = {self.optim.update_processes} computes gradients in CPU processes; with "
                f"device {self.device!r} set update_processes = 1"
            )
        self._check_collection(amat)
        if amat.critic == "state" and self.imitation.warm_start:
            raise ValueError(
                "amat critic 'state' is PPO's: set no warm_start (imitate with critic 'encoder' first, then "
                "init_from that run)"
            )
        envs = [("the env's", self.env_config())]  # validates them
        if self.env.worlds:
            envs += [(f"worlds[{k}]'s", env) for k, (env, _) in enumerate(self.world_configs())]
        for where, env in envs:
            if amat.window != env.window:
                raise ValueError(f"AMAT window {amat.window} differs from {where} goal window {env.window}")
            if amat.local_size != env.local_size or amat.n_classes != env.num_classes:
                raise ValueError(f"AMAT local_size / n_classes must match {where} local map and classes")

    def _check_losses(self, amat: AmatConfig) -> None:
        """The auxiliary losses' fields together: the anchor and its weight, the relay labels' planners and
        model, the anchor's place of the rescue loss."""
        loss, imitation = self.loss, self.imitation
        if bool(loss.anchor) != (loss.anchor_coef > 0):
            raise ValueError("TrainConfig.anchor and anchor_coef > 0 go together: set both, or neither")
        if loss.anchor_on == "relay" and loss.anchor not in RELAY_PLANNERS:
            raise ValueError(
                f"TrainConfig.anchor_on 'relay' needs a relay planner as the anchor: one of {RELAY_PLANNERS}"
            )
        relay_teacher = imitation.warm_start in RELAY_PLANNERS and amat.goals == "cell"
        if imitation.warm_start_relay > 0 and not relay_teacher:
            raise ValueError(
                "TrainConfig.warm_start_relay > 0 weighs a relay teacher's relay labels for a cell-goal "
                f"model (amat goals 'cell'): warm_start one of {RELAY_PLANNERS}"
            )
        if loss.anchor and (loss.rescue_coef > 0 or amat.goals != "cell"):
            raise ValueError(
                "TrainConfig.anchor labels a cell-goal model's decisions (amat goals 'cell') and takes the "
                "rescue loss's place: set rescue_coef = 0"
            )

    def _check_collection(self, amat: AmatConfig) -> None:
        """What only the local collector does (labels from a planner in this process, a mixture of worlds,
        the state critic's state) refused with Ray, and Ray's share of the worlds."""
        collection = self.collection
        if collection.collector == "local":
            return
        if self.imitation.warm_start:
            raise ValueError(
                "TrainConfig.warm_start needs collector 'local' (DAgger labels decisions with a planner "
                "in this process); warm-start locally, then --resume with --collector ray "
                "--set warm_start=''"
            )
        if self.loss.rescue_coef > 0 or self.loss.anchor:
            raise ValueError(
                "TrainConfig.rescue_coef > 0 and anchor need collector 'local' (the rule or planner labels "
                "decisions in this process); set them off with --collector ray"
            )
        if collection.num_worlds % collection.ray_workers:
            raise ValueError(
                f"num_worlds ({collection.num_worlds}) must be divisible by ray_workers "
                f"({collection.ray_workers}): each Ray worker collects an equal share of the worlds"
            )
        if self.env.worlds:
            raise ValueError("TrainConfig.worlds (a mixture of worlds) needs collector 'local'")
        if amat.critic == "state":
            raise ValueError("amat critic 'state' needs collector 'local' (it collects the true state)")

    def env_config(self) -> EnvConfig:
        return self._for_model(make_config(self.env.env_preset, **self.env.env_overrides))

    def _for_model(self, env: EnvConfig) -> EnvConfig:
        """``env`` with the teammate memory on when the model reads it (``AmatConfig.teammate_memory``, and
        ``teammate_heading``)."""
        shown = {k: True for k in ("teammate_memory", "teammate_heading") if self.model.amat.get(k)}
        return env.replace(**shown) if shown else env

    def world_configs(self) -> list[tuple[EnvConfig, int]]:
        """(EnvConfig, episodes per iteration) of each training world (see ``worlds``); ValueError
        naming a bad entry."""
        num_worlds = self.collection.num_worlds
        if not self.env.worlds:
            return [(self.env_config(), num_worlds)]
        out = []
        for k, entry in enumerate(self.env.worlds):
            entry = dict(entry)
            preset, n = entry.pop("preset", None), entry.pop("num_worlds", num_worlds)
            check(f"TrainConfig.worlds[{k}]", "num_worlds", n, INT(">= 1", lambda v: v >= 1))
            try:
                env = make_config(preset, **entry) if preset else self.env_config().replace(**entry)
                env = self._for_model(env)
            except (ValueError, TypeError) as err:
                raise ValueError(f"TrainConfig.worlds[{k}]: {err}") from None
            out.append((env, n))
        return out

    def eval_env_config(self) -> EnvConfig:
        """The training task with evaluation activation (0, 0)."""
        return self.env_config().replace(activation=(0, 0))

    def amat_config(self) -> AmatConfig:
        return AmatConfig.from_dict(self.model.amat)

    def replace(self, **changes: Any) -> TrainConfig:
        """This config with ``changes``: fields by their flat names (``lr=3e-4``), a section by its name,
        as a section or as a JSON object of some of its fields (``optim={"lr": 3e-4}``, as the sectioned
        JSON holds it). A ValueError names an unknown field."""
        fields = _fields()
        pairs: list[tuple[str, Any]] = []  # (flat name, value)
        new: dict[str, Any] = {}  # TrainConfig's own fields, and whole sections
        for name, value in changes.items():
            if name in SECTIONS and isinstance(value, dict):
                pairs += _section_items(name, value).items()
            elif name in SECTIONS:
                new[name] = value  # checked as built
            else:
                pairs.append((name, value))
        flat = dict(pairs)
        unknown = sorted(set(flat) - set(fields))
        if unknown:
            raise ValueError(f"unknown TrainConfig field(s) {unknown}; valid fields: {sorted(fields)}")
        if len(flat) < len(pairs):
            twice = sorted({k for k, _ in pairs if [n for n, _ in pairs].count(k) > 1})
            raise ValueError(f"TrainConfig field(s) {twice} given twice (flat and in their section)")
        grouped: dict[str, dict[str, Any]] = {}
        for name, value in flat.items():
            home = fields[name][0]
            if home:
                grouped.setdefault(home, {})[name] = value
            else:
                new[name] = value
        for home, group in grouped.items():
            new[home] = dataclasses.replace(new.get(home, getattr(self, home)), **group)
        return dataclasses.replace(self, **new)

    def to_dict(self) -> dict[str, Any]:
        """Every field by its flat name (a copy): the object of config.json."""
        out = {}
        for name, value in dataclasses.asdict(self).items():
            out |= value if name in SECTIONS else {name: value}
        return out

    def to_json(self) -> str:
        """The flat form (see the module's docstring), keys sorted."""
        return json.dumps(self.to_dict(), indent=2, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> TrainConfig:
        """The config of a JSON object: flat (``to_json``'s form, and every config.json written before the
        sections) or sectioned (``{"optim": {"lr": 0.0001}, "seed": 0}``), each field at most once; the
        fields it lacks at their defaults."""
        return cls().replace(**json.loads(text))


def _section_items(name: str, values: dict[str, Any]) -> dict[str, Any]:
    """``values``, a JSON object of section ``name``'s fields; a ValueError naming a field it lacks."""
    own = [f.name for f in dataclasses.fields(SECTIONS[name])]
    unknown = sorted(set(values) - set(own))
    if unknown:
        unknown = [f"{name}.{k}" for k in unknown]
        raise ValueError(f"unknown TrainConfig field(s) {unknown}; the {name} section's fields: {own}")
    return values
