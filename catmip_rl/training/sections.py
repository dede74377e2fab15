"""The sections of a TrainConfig (``training.config``), grouped as TorchRL's recipes group theirs; each a
frozen dataclass of fields, one docstring each (``catmip train --help`` shows them), checked by the
TrainConfig that holds it:

    env         the training worlds: env_preset, env_overrides, worlds
    model       AMAT: amat, init_from
    collection  who collects how many episodes: num_worlds, collector, ray_workers, ray_address
    loss        PPO's loss and advantages: clip, value_clip, huber_delta, entropy_coef, value_coef, the
                auxiliary label loss (rescue_coef, rescue_heading, anchor, anchor_coef, anchor_on), gamma, lam
    optim       the steps and their schedule: iterations, budget_minutes, lr, critic_lr, adam_eps,
                max_grad_norm, epochs, minibatches, micro_batch, target_kl, value_warmup_iterations,
                precision, update_processes
    imitation   the DAgger warm start (training.imitation): warm_start and the warm_start_* fields
    eval        eval_every, eval_episodes, eval_seed

and the run's own fields on TrainConfig itself: seed, device, threads, checkpoint_every. A field's name is
unique across them all, so that it names the field alone: ``catmip train``'s flags, ``--set FIELD=VALUE``,
``TrainConfig.replace`` and the saved config.json use these flat names (``lr``, not ``optim.lr``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

__all__ = [
    "EnvSection",
    "ModelSection",
    "CollectionSection",
    "LossSection",
    "OptimSection",
    "ImitationSection",
    "EvalSection",
    "SECTIONS",
]


@dataclass(frozen=True)
class EnvSection:
    """The training worlds (the evaluation plays ``env_preset`` + ``env_overrides``)."""

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


@dataclass(frozen=True)
class ModelSection:
    """The model trained, and the weights it starts from."""

    amat: dict[str, Any] = field(default_factory=dict)
    """AmatConfig field overrides (window must equal the env's window)."""
    init_from: str = ""
    """Start a new run from these weights instead of a fresh initialisation: a model file, a training
    checkpoint or run dir (its value normaliser comes too) or a shipped model's name; "" = none. The
    model must be an AMAT of this run's ``amat`` config. A warm start, if any, then begins from them;
    the optimiser and the LR schedule start afresh (fine-tuning). Not read when a run resumes."""


@dataclass(frozen=True)
class CollectionSection:
    """Who collects the episodes of an iteration, and how many."""

    num_worlds: int = 64
    """Worlds (= episodes) collected per iteration."""
    collector: str = "local"
    """Where episodes are collected: "local" (this process) or "ray" (Ray workers, the distributed extra)."""
    ray_workers: int = 2
    """Ray collector workers; each collects num_worlds / ray_workers worlds per iteration."""
    ray_address: str | None = None
    """Ray cluster to join ("auto", "host:port", "ray://host:port"); None starts a local one on loopback."""


@dataclass(frozen=True)
class LossSection:
    """PPO's loss, its auxiliary label loss and the advantages it weighs."""

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
    gamma: float = 1.0
    """Discount per tick."""
    lam: float = 0.95
    """GAE lambda along each robot's activations."""


@dataclass(frozen=True)
class OptimSection:
    """The optimiser's steps: how many, how large, in which precision and on how many processes."""

    iterations: int = 62_500
    """PPO iterations (the LR decays linearly to 0 over them, or over ``budget_minutes``)."""
    budget_minutes: float = 0.0
    """Wall-clock budget of the run in minutes of training (0 = none): training stops once it is spent,
    and the LR decays linearly to 0 over whichever of the iterations and the budget runs out first."""
    lr: float = 1e-4
    """Adam learning rate (decays linearly to 0 over the run)."""
    critic_lr: float = 0.0
    """The critic's own parameters' learning rate (the value head's, or the state critic's), decaying
    alike; 0: ``lr``. A new critic beside a trained policy learns at the policy's fine-tuning rate only
    slowly."""
    adam_eps: float = 1e-5
    """Adam epsilon."""
    max_grad_norm: float = 10.0
    """Gradient-norm clip of each step."""
    epochs: int = 10
    """PPO epochs per iteration."""
    minibatches: int = 1
    """Minibatches per epoch (1 = full batch)."""
    micro_batch: int = 512
    """Decision events per forward/backward pass: a minibatch's gradient is accumulated over its
    micro-batches (the same gradient, in bounded memory and faster on CPU caches); 0 = one pass."""
    target_kl: float = 0.0
    """Step control (0 = off): an iteration's epochs stop at the first minibatch whose approx-KL from
    the collecting policy exceeds this (measured before that minibatch's step, which is skipped)."""
    value_warmup_iterations: int = 0
    """First PPO iterations that train the value head alone (the policy stays as imitated)."""
    precision: str = "fp32"
    """PPO update precision: "fp32", "bf16" (bfloat16 autocast) or "auto" (bf16 where the CPU has it
    natively, training.ppo.choose_bf16; else fp32)."""
    update_processes: int = 1
    """Processes computing the PPO update's gradients (CPU): 1 = this one, on ``threads`` threads; n > 1 =
    this one and n - 1 helpers, one thread each, sharing every minibatch's micro-batches (data parallel,
    the same update to float32 rounding; ~15 % faster than one process with two threads on 2 cores)."""


@dataclass(frozen=True)
class ImitationSection:
    """The imitation warm start before PPO (catmip_rl.training.imitation): DAgger rounds."""

    warm_start: str = ""
    """Imitation warm start before PPO (catmip_rl.training.imitation): a planner name ("nearest", "rrt", ...)
    whose goals, projected into the window, label DAgger rounds; "" = none (the paper's recipe)."""
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


@dataclass(frozen=True)
class EvalSection:
    """The evaluation during training: argmax and sampled play on a fixed map set."""

    eval_every: int = 50
    """Iterations between evaluations (0 = never)."""
    eval_episodes: int = 32
    """Episodes (fixed maps) of each evaluation."""
    eval_seed: int = 12_345
    """Seed of the fixed evaluation map set."""


#: each section's name in a TrainConfig (``cfg.optim``), and its class
SECTIONS: dict[str, type] = {
    "env": EnvSection,
    "model": ModelSection,
    "collection": CollectionSection,
    "loss": LossSection,
    "optim": OptimSection,
    "imitation": ImitationSection,
    "eval": EvalSection,
}
