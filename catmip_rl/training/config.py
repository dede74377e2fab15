"""Training configuration: one frozen dataclass, validated when built, saved as JSON in every run dir
(its presets: catmip_rl.training.presets)."""

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

__all__ = ["TrainConfig", "check_field", "field_docs"]


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
def _rules() -> dict[str, Rule]:
    """Every field's rule (catmip_env.fields): its type, range or values."""
    out = {}
    for f in dataclasses.fields(TrainConfig):
        rule = _VALUES.get(f.name) or _TYPES[f.type]
        out[f.name] = rule(*_RANGES[f.name]) if f.name in _RANGES else rule
    return out


def check_field(name: str, value: Any) -> None:
    """A ValueError naming the field unless ``value`` is of the field's annotated type (an int field a
    real int, never a bool; a float field a finite number) and in its range or values: "TrainConfig.
    eval_seed must be an int >= 0 and < 2**64, got 1.5". The one check of a field's value, for the
    config and for ``catmip train``'s flags (the same validator as EnvConfig's: catmip_env.fields)."""
    check("TrainConfig", name, value, _rules()[name])


@cache
def field_docs() -> dict[str, str]:
    """Each documented TrainConfig field's docstring (the string under it in this file), whitespace
    collapsed: the help of ``catmip train``'s flags."""
    tree = ast.parse(Path(__file__).read_text())
    body = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "TrainConfig").body
    docs = {}
    for node, after in zip(body, body[1:]):
        documented = isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant)
        if isinstance(node, ast.AnnAssign) and documented:
            docs[node.target.id] = " ".join(str(after.value.value).split())
    return docs


@dataclass(frozen=True)
class TrainConfig:
    """The paper's recipe (docs/design.md#ppo-recipe) by default."""

    env_preset: str = "train"
    """catmip_env preset the training worlds come from."""
    env_overrides: dict[str, Any] = field(default_factory=dict)
    """EnvConfig field overrides (e.g. {"synchronous": true})."""
    worlds: list[dict[str, Any]] = field(default_factory=list)
    """A mixture of training worlds; empty (default): the one world ``env_preset`` + ``env_overrides``.
    Each entry is a JSON object of EnvConfig overrides applied over that world, with two keys of its
    own: "preset" (start from this catmip_env preset instead, without ``env_overrides``) and
    "num_worlds" (episodes collected per iteration in this world; default ``num_worlds``). PPO iteration
    k trains on world (k - 1) mod len(worlds); the warm start's DAgger rounds, if any, collect from every
    world (a buffer each); the evaluation stays on ``env_preset`` + ``env_overrides``."""
    amat: dict[str, Any] = field(default_factory=dict)
    """AmatConfig field overrides (window must equal the env's window)."""
    num_worlds: int = 64
    """Worlds (= episodes) collected per iteration."""
    iterations: int = 62_500
    """PPO iterations (the LR decays linearly to 0 over them, or over ``budget_minutes``)."""
    budget_minutes: float = 0.0
    """Wall-clock budget of the run in minutes of training (0 = none): training stops once it is spent,
    and the LR decays linearly to 0 over whichever of the iterations and the budget runs out first."""
    target_kl: float = 0.0
    """Step control (0 = off): an iteration's epochs stop at the first minibatch whose approx-KL from
    the collecting policy exceeds this (measured before that minibatch's step, which is skipped)."""
    epochs: int = 10
    """PPO epochs per iteration."""
    minibatches: int = 1
    """Minibatches per epoch (1 = full batch)."""
    micro_batch: int = 512
    """Decision events per forward/backward pass: a minibatch's gradient is accumulated over its
    micro-batches (the same gradient, in bounded memory and faster on CPU caches); 0 = one pass."""
    lr: float = 1e-4
    """Adam learning rate (decays linearly to 0 over the run)."""
    critic_lr: float = 0.0
    """The critic's own parameters' learning rate (the value head's, or the state critic's), decaying
    alike; 0: ``lr``. A new critic beside a trained policy learns at the policy's fine-tuning rate only
    slowly."""
    adam_eps: float = 1e-5
    """Adam epsilon."""
    clip: float = 0.05
    """PPO ratio clip epsilon."""
    value_clip: float = 0.05
    """Clip of the value prediction around the old value (normalised units)."""
    huber_delta: float = 10.0
    """Delta of the Huber value loss."""
    entropy_coef: float = 0.01
    """Weight of the entropy bonus."""
    value_coef: float = 1.0
    """Weight of the value loss."""
    rescue_coef: float = 0.0
    """Weight of an auxiliary cross-entropy toward the planners' rescue rule (projected into the window)
    for active rescuers that know the target (catmip_rl.training.labelers.RescueLabeler); 0 = the
    paper's loss. Collection then also labels those decisions."""
    rescue_heading: bool = True
    """Whether the rescue loss's label projects the way to the target into the window along the
    controller's own path, which starts in the robot's heading (``window:nearest``), or along a
    heading-free one (``window-noheading:nearest``): a label that depends only on what AMAT observes."""
    anchor: str = ""
    """A planner (e.g. "rrt") whose own cell goal labels every decision of a cell-goal model during PPO,
    for an auxiliary cross-entropy weighted by ``anchor_coef`` (it takes the rescue loss's place, and
    its ``loss/rescue`` column): PPO moves the policy where the advantage says while the anchor keeps
    it near the planner it imitated, so that argmax play does not drift into loops. "" = none."""
    anchor_coef: float = 0.0
    """Weight of the ``anchor`` loss (> 0 exactly when ``anchor`` is set)."""
    anchor_on: str = "every"
    """Which decisions the ``anchor`` labels: "every" one, or only those where a relay planner's relay
    rule chooses ("relay": an explorer carrying the news of the target to a rescuer; ``planners.Relay``),
    so that the anchor teaches the relay and leaves the rest of the policy to PPO."""
    max_grad_norm: float = 10.0
    """Gradient-norm clip of each step."""
    gamma: float = 1.0
    """Discount per tick."""
    lam: float = 0.95
    """GAE lambda along each robot's activations."""
    seed: int = 0
    """Seed of the training worlds, the initial weights and the sampling."""
    device: str = "cpu"
    """Where the model trains: cpu, cuda or cuda:N."""
    threads: int = 2
    """torch CPU threads."""
    precision: str = "fp32"
    """PPO update precision: "fp32", "bf16" (bfloat16 autocast) or "auto" (bf16 where the CPU has it
    natively, training.ppo.choose_bf16; else fp32)."""
    update_processes: int = 1
    """Processes computing the PPO update's gradients (CPU): 1 = this one, on ``threads`` threads; n > 1 =
    this one and n - 1 helpers, one thread each, sharing every minibatch's micro-batches (data parallel,
    the same update to float32 rounding; ~15 % faster than one process with two threads on 2 cores)."""
    warm_start: str = ""
    """Imitation warm start before PPO (catmip_rl.training.imitation): a planner name ("nearest", "rrt", ...)
    whose goals, projected into the window, label DAgger rounds; "" = none (the paper's recipe)."""
    init_from: str = ""
    """Start a new run from these weights instead of a fresh initialisation: a model file, a training
    checkpoint or run dir (its value normaliser comes too) or a shipped model's name; "" = none. The
    model must be an AMAT of this run's ``amat`` config. A warm start, if any, then begins from them;
    the optimiser and the LR schedule start afresh (fine-tuning). Not read when a run resumes."""
    warm_start_heading: bool = True
    """Whether the teacher projects a far goal into the window along the controller's own path, which
    starts in the robot's heading (``window:PLANNER``), or along a heading-free one (E, S, W, N first,
    then straight on: ``window-noheading:PLANNER``), a label that depends only on what AMAT observes (no
    headings); measured, it taught no better (docs/notes/paper-model.md, "A teacher that turns less")."""
    warm_start_stay: bool = True
    """Whether the teacher's "stay" labels are imitated. The window planner says "stay" when its planner
    has no goal (no reachable frontier it may claim): a pause for the teacher, whose next decision
    differs as the others move, but a state a deterministic student learns to stand still in, deciding
    the same again at once (an argmax loop). False leaves those decisions unscored."""
    warm_start_value: bool = False
    """Whether the warm start also regresses the value head on the rollouts' returns (and sets the value
    normaliser by them), so that PPO starts with a critic. Measured on the cell-goal model: imitation
    alone left its encoder's output the same for every robot (the pointer needs only the per-cell
    features), and a value head on it cannot learn (docs/notes/general-model.md)."""
    warm_start_relay: float = 0.0
    """Weight of a second cross-entropy in every DAgger step, over the labels a relay teacher's relay rule
    chose (``rrt-relay``, ``rrt-relay-heading``, ...: which teammate to carry the news to, and where),
    on a quarter batch of the events that hold one; 0 = none. These labels are a rule's, and a few in a
    hundred: the uniform batches left a student agreeing with under half of them
    (docs/notes/general-model.md, "Relay-focused DAgger")."""
    warm_start_worlds: int = 0
    """Episodes each DAgger round collects (0 = ``num_worlds``). Collection is cheap beside the round's
    cross-entropy steps, and with few episodes a round's steps fit the buffer rather than the teacher
    (measured on Task 1: 64 episodes a round imitate to 0.72 by tick 100, 256 to 0.98;
    docs/notes/training-experiments.md)."""
    warm_start_rounds: int = 6
    """DAgger rounds (each collects warm_start_worlds episodes of every training world with the current
    policy, labelled)."""
    warm_start_steps: int = 150
    """Cross-entropy gradient steps per DAgger round, on minibatches of warm_start_batch events."""
    warm_start_batch: int = 256
    """Events per cross-entropy step of the warm start."""
    warm_start_lr: float = 1e-3
    """Adam learning rate of the warm start."""
    value_warmup_iterations: int = 0
    """First PPO iterations that train the value head alone (the policy stays as imitated)."""
    eval_every: int = 50
    """Iterations between evaluations (0 = never)."""
    eval_episodes: int = 32
    """Episodes (fixed maps) of each evaluation."""
    eval_seed: int = 12_345
    """Seed of the fixed evaluation map set."""
    checkpoint_every: int = 50
    """Iterations between checkpoints, and one at the end (0 = none: the run cannot be resumed)."""
    collector: str = "local"
    """Where episodes are collected: "local" (this process) or "ray" (Ray workers, the distributed extra)."""
    ray_workers: int = 2
    """Ray collector workers; each collects num_worlds / ray_workers worlds per iteration."""
    ray_address: str | None = None
    """Ray cluster to join ("auto", "host:port", "ray://host:port"); None starts a local one on loopback."""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            check_field(f.name, getattr(self, f.name))
        amat = self.amat_config()  # validates it
        if bool(self.anchor) != (self.anchor_coef > 0):
            raise ValueError("TrainConfig.anchor and anchor_coef > 0 go together: set both, or neither")
        if self.anchor_on == "relay" and self.anchor not in RELAY_PLANNERS:
            raise ValueError(
                f"TrainConfig.anchor_on 'relay' needs a relay planner as the anchor: one of {RELAY_PLANNERS}"
            )
        if self.warm_start_relay > 0 and not (self.warm_start in RELAY_PLANNERS and amat.goals == "cell"):
            raise ValueError(
                "TrainConfig.warm_start_relay > 0 weighs a relay teacher's relay labels for a cell-goal "
                f"model (amat goals 'cell'): warm_start one of {RELAY_PLANNERS}"
            )
        if self.anchor and (self.rescue_coef > 0 or amat.goals != "cell"):
            raise ValueError(
                "TrainConfig.anchor labels a cell-goal model's decisions (amat goals 'cell') and takes the "
                "rescue loss's place: set rescue_coef = 0"
            )
        if self.update_processes > 1 and self.device != "cpu":
            raise ValueError(
                f"update_processes = {self.update_processes} computes gradients in CPU processes; with "
                f"device {self.device!r} set update_processes = 1"
            )
        self._check_collection(amat)
        if amat.critic == "state" and self.warm_start:
            raise ValueError(
                "amat critic 'state' is PPO's: set no warm_start (imitate with critic 'encoder' first, then "
                "init_from that run)"
            )
        envs = [("the env's", self.env_config())]  # validates them
        if self.worlds:
            envs += [(f"worlds[{k}]'s", env) for k, (env, _) in enumerate(self.world_configs())]
        for where, env in envs:
            if amat.window != env.window:
                raise ValueError(f"AMAT window {amat.window} differs from {where} goal window {env.window}")
            if amat.local_size != env.local_size or amat.n_classes != env.num_classes:
                raise ValueError(f"AMAT local_size / n_classes must match {where} local map and classes")

    def _check_collection(self, amat: AmatConfig) -> None:
        """What only the local collector does (labels from a planner in this process, a mixture of worlds,
        the state critic's state) refused with Ray, and Ray's share of the
        worlds."""
        if self.collector == "local":
            return
        if self.warm_start:
            raise ValueError(
                "TrainConfig.warm_start needs collector 'local' (DAgger labels decisions with a planner "
                "in this process); warm-start locally, then --resume with --collector ray "
                "--set warm_start=''"
            )
        if self.rescue_coef > 0 or self.anchor:
            raise ValueError(
                "TrainConfig.rescue_coef > 0 and anchor need collector 'local' (the rule or planner labels "
                "decisions in this process); set them off with --collector ray"
            )
        if self.num_worlds % self.ray_workers:
            raise ValueError(
                f"num_worlds ({self.num_worlds}) must be divisible by ray_workers ({self.ray_workers}): "
                "each Ray worker collects an equal share of the worlds"
            )
        if self.worlds:
            raise ValueError("TrainConfig.worlds (a mixture of worlds) needs collector 'local'")
        if amat.critic == "state":
            raise ValueError("amat critic 'state' needs collector 'local' (it collects the true state)")

    def env_config(self) -> EnvConfig:
        return self._for_model(make_config(self.env_preset, **self.env_overrides))

    def _for_model(self, env: EnvConfig) -> EnvConfig:
        """``env`` with the teammate memory on when the model reads it (``AmatConfig.teammate_memory``, and
        ``teammate_heading``)."""
        shown = {k: True for k in ("teammate_memory", "teammate_heading") if self.amat.get(k)}
        return env.replace(**shown) if shown else env

    def world_configs(self) -> list[tuple[EnvConfig, int]]:
        """(EnvConfig, episodes per iteration) of each training world (see ``worlds``); ValueError
        naming a bad entry."""
        if not self.worlds:
            return [(self.env_config(), self.num_worlds)]
        out = []
        for k, entry in enumerate(self.worlds):
            entry = dict(entry)
            preset, n = entry.pop("preset", None), entry.pop("num_worlds", self.num_worlds)
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
        return AmatConfig.from_dict(self.amat)

    def replace(self, **changes: Any) -> TrainConfig:
        names = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(changes) - names)
        if unknown:
            raise ValueError(f"unknown TrainConfig field(s) {unknown}; valid fields: {sorted(names)}")
        return dataclasses.replace(self, **changes)

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), indent=2, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> TrainConfig:
        return cls().replace(**json.loads(text))
