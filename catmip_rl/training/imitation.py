"""Imitation warm start (DAgger) from a classical planner: projected into the goal window for the paper's
AMAT, the planner itself for the cell-goal model (``amat.pointer``).

    model = make_model(cfg.amat_config())
    collector = Collector(cfg.env_config(), cfg.collection.num_worlds, seed=0, goal_mode=model.config.goals)
    episodes, log = dagger(model, collector, "nearest", rounds=6, steps_per_round=300)  # then PPO

Each round rolls out the current policy on ``cfg.collection.num_worlds`` new training episodes while the
teacher (:class:`~catmip_env.planners.window.WindowPlanner`: the planner's goal, projected into the
robot's window; or the planner's own cell goal; the rescue rule for a rescuer that knows the target)
labels every active robot's decision; with
probability ``beta`` (1 in round 0, halving every round) a robot executes the label instead, DAgger's
mixture. The labelled events are aggregated over the rounds (up to ``buffer_events``, the oldest
dropped first) and AMAT's decoder is trained by cross-entropy on them, teacher-forced in the decision
order of PPO (active robots first, each fed the previous robot's label). Busy robots are inputs only.
:func:`warm_start` runs these rounds for ``catmip train --warm-start``, logging each round to
``RUN_DIR/warm_start.csv``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from catmip_env.planners.baselines import Relay
from catmip_env.play import Policy
from catmip_rl.amat.inputs import one_hot_class
from catmip_rl.amat.model import AMAT, INVALID_LOGIT
from catmip_rl.store.files import open_csv_log, write_csv_row
from catmip_rl.training.collect import Collector, Rollout
from catmip_rl.training.gae import ValueNorm, async_gae
from catmip_rl.training.labelers import make_teacher

__all__ = [
    "DemoBuffer",
    "imitation_loss",
    "dagger",
    "warm_start",
    "WARM_START_METRICS",
]

WARM_START_METRICS = [
    "round",
    "episodes",
    "beta",
    "buffer_events",
    "rollout/success_rate",
    "rollout/success_by_100",
    "imitation/loss",
    "imitation/accuracy",
    "imitation/outside_mask",
    "imitation/value_loss",
    "imitation/relay_loss",
    "imitation/relay_accuracy",
    "eval/success_rate",
    "eval/success_by_100",
    "eval/sampled_success_rate",
    "eval/sampled_success_by_100",
    "time/collect_s",
    "time/update_s",
    "time/elapsed_min",
]
_KEYS = ("global_map", "local_map", "agent_class", "neighbourhood", "action_mask", "active", "order", "label")


@dataclass
class DemoBuffer:
    """Labelled decision events aggregated over DAgger rounds (numpy, rows = events)."""

    max_events: int
    arrays: dict[str, np.ndarray] | None = None
    #: indices of the events with a label the teacher's relay rule chose (set by :meth:`add`)
    relay_events: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    def __len__(self) -> int:
        return 0 if self.arrays is None else len(self.arrays["label"])

    def add(self, r: Rollout, gamma: float = 1.0) -> np.ndarray:
        """Append a labelled rollout's events, with each finished decision's discounted return (Monte
        Carlo: async GAE with zero values and lambda 1) for the value head; returns those returns."""
        if r.label is None:
            raise ValueError("DemoBuffer.add needs a rollout collected with a labeler")
        rows = r.valid
        # busy robots keep the stored action as their (unused) label: they are never scored
        label = np.where(r.active, r.label, r.action)
        new = {k: np.ascontiguousarray((label if k == "label" else getattr(r, k))[rows]) for k in _KEYS}
        # the labels a relay teacher's relay rule chose (none for another teacher)
        new["relay"] = r.label_relay[rows] if r.label_relay is not None else np.zeros_like(new["active"])
        new["hint"] = r.hint[rows]  # the proposals of the model's AmatConfig.hint planner (-1: none)
        zeros = np.zeros(r.active.shape)
        _, ret, trainable = async_gae(
            r.active,
            r.valid,
            zeros,
            r.ma_return,
            r.ma_ticks.astype(np.int64),
            r.final_return,
            r.terminated,
            gamma,
            1.0,
        )
        new["value_target"], new["value_trainable"] = ret[rows].astype(np.float32), trainable[rows]
        if self.arrays is not None:
            new = {k: np.concatenate([self.arrays[k], v]) for k, v in new.items()}
        self.arrays = {k: v[-self.max_events :] for k, v in new.items()}
        self.relay_events = np.flatnonzero(self.arrays["relay"].any(1))
        return ret[rows][trainable[rows]]

    def batch(self, idx: np.ndarray, n_classes: int, device: torch.device) -> dict[str, torch.Tensor]:
        a = self.arrays
        out = {k: torch.from_numpy(a[k][idx]) for k in a if k != "agent_class"}
        out["agent_class"] = one_hot_class(a["agent_class"][idx], n_classes)
        return {k: v.to(device) for k, v in out.items()}


def imitation_loss(
    model: AMAT,
    batch: dict[str, torch.Tensor],
    skip_label: int | None = None,
    value_norm: ValueNorm | None = None,
    value_coef: float = 1.0,
) -> tuple[torch.Tensor, dict[str, float]]:
    """Mean cross-entropy of the active robots' labels under teacher forcing, and its accuracy; decisions
    labelled ``skip_label`` are not scored (they still feed the decoder as inputs), nor are labels the
    model's own mask rules out (the cell-goal model narrows the environment's mask: ``amat.pointer``),
    whose share of the labels is reported as ``imitation/outside_mask`` (a teacher whose goals the model
    cannot choose shows there, not as a silent loss of data). With ``value_norm``, ``value_coef`` times
    the squared error of the value head against the finished decisions' returns (``value_target``,
    normalised) is added (``imitation/value_loss``): a critic for the PPO that follows, and a reason for
    the encoder to keep what the policy alone may not need."""
    inputs = ("global_map", "local_map", "agent_class", "neighbourhood", "hint")
    obs = {k: batch[k] for k in inputs if k in batch}
    sel = batch["active"].bool()
    if skip_label is not None:
        sel = sel & (batch["label"] != skip_label)
    value_loss = None
    if sel.any():
        logits, values = model.score(
            model.embed(obs), batch["label"], batch["order"], batch["agent_class"], sel, batch["action_mask"]
        )  # (K, A), (K, 1)
        if value_norm is not None:
            fit = batch["value_trainable"][sel]
            target_v = value_norm.normalize(batch["value_target"][sel][fit].double()).float()
            value_loss = torch.nn.functional.mse_loss(values[fit, 0].float(), target_v) if fit.any() else None
        target = batch["label"][sel]
        inside = logits.gather(1, target[:, None])[:, 0] > INVALID_LOGIT / 2
        logits, target = logits[inside], target[inside]
    outside = 1.0 - len(target) / int(sel.sum()) if sel.any() else 0.0
    if not sel.any() or len(target) == 0:
        zero = sum(p.sum() * 0.0 for p in model.parameters())  # no label in this batch: no step
        return zero, {"imitation/loss": 0.0, "imitation/accuracy": 0.0, "imitation/outside_mask": outside}
    loss = torch.nn.functional.cross_entropy(logits.float(), target)
    with torch.no_grad():
        acc = (logits.argmax(-1) == target).float().mean()
    stats = {"imitation/loss": float(loss.detach()), "imitation/accuracy": float(acc)}
    if value_loss is not None:
        loss = loss + value_coef * value_loss
        stats["imitation/value_loss"] = float(value_loss.detach())
    return loss, stats | {"imitation/outside_mask": outside}


def dagger(
    model: AMAT,
    collector: Collector | list[Collector],
    teacher: str | Policy,
    rounds: int,
    steps_per_round: int,
    batch_events: int = 256,
    lr: float = 1e-3,
    buffer_events: int = 200_000,
    first_episode: int = 0,
    generator: torch.Generator | None = None,
    seed: int = 0,
    max_grad_norm: float = 10.0,
    deterministic: bool = False,
    on_round=None,
    follow_heading: bool = True,
    imitate_stay: bool = True,
    value_norm: ValueNorm | None = None,
    gamma: float = 1.0,
    relay_weight: float = 0.0,
) -> tuple[int, list[dict[str, float]]]:
    """Train ``model`` by DAgger against ``teacher``: a planner's name (the teacher for the model's goals,
    :func:`make_teacher`, seeded by ``seed``) or the teacher itself; returns (episodes used, one log row
    per round). The policy's own actions in the rollouts are argmax with ``deterministic`` (as it will
    be evaluated), else sampled. ``on_round(row)`` is called after each
    round (logging, progress). A list of collectors (a mixture of worlds) collects from each every
    round into a buffer of its own (their maps differ in size and team), and the steps take their
    batches from the buffers in turn. ``follow_heading=False`` projects a named teacher's goals along a
    heading-free path (:class:`~catmip_env.planners.window.WindowPlanner`). ``imitate_stay=False`` leaves
    the teacher's "stay" labels unscored (``TrainConfig.warm_start_stay``). With ``value_norm`` the value
    head learns the rollouts' returns (discounted by ``gamma``) beside the labels, and ``value_norm``
    follows them (:func:`imitation_loss`; ``TrainConfig.warm_start_value``). With ``relay_weight`` > 0
    (a relay teacher, ``planners.Relay``) every step adds that weight times the cross-entropy of the
    labels its relay rule chose, on a quarter batch of the events that hold one
    (``TrainConfig.warm_start_relay``)."""
    if rounds < 1 or steps_per_round < 1 or batch_events < 1:
        raise ValueError("dagger: rounds, steps_per_round and batch_events must be >= 1")
    gen = generator if generator is not None else torch.Generator().manual_seed(seed)
    rng = np.random.default_rng(seed)
    if isinstance(teacher, str):
        teacher = make_teacher(teacher, model.config.goals, seed=seed, follow_heading=follow_heading)
    if relay_weight > 0 and not isinstance(teacher, Relay):
        raise ValueError(f"dagger: relay_weight needs a relay planner as the teacher, not {teacher.name!r}")
    collectors = collector if isinstance(collector, list) else [collector]
    buffers = [DemoBuffer(buffer_events // len(collectors)) for _ in collectors]
    if not imitate_stay and model.config.goals != "window":
        raise ValueError("imitate_stay=False is for window goals (a cell model's 'stay' is the robot's cell)")
    skip = None if imitate_stay else model.config.num_actions // 2  # the window's centre: "stay"
    opt = torch.optim.Adam(model.parameters(), lr=lr, eps=1e-5)
    episodes = first_episode
    log = []
    for r in range(rounds):
        t0 = time.perf_counter()
        beta = 0.5**r
        stats = []
        for col, buffer in zip(collectors, buffers):
            rollout = col.collect(
                model, episodes, gen, deterministic=deterministic, labeler=teacher, teacher_prob=beta
            )
            episodes += col.num_worlds
            returns = buffer.add(rollout, gamma)
            if value_norm is not None and len(returns):
                value_norm.update(torch.from_numpy(returns))
            stats.append(rollout.stats)
        t1 = time.perf_counter()
        model.train()
        steps = [
            _imitation_step(
                model,
                opt,
                buffers[k % len(buffers)],
                rng,
                batch_events,
                skip,
                value_norm,
                relay_weight,
                max_grad_norm,
            )
            for k in range(steps_per_round)
        ]
        keys = ["imitation/loss", "imitation/accuracy", "imitation/outside_mask"]
        keys += ["imitation/value_loss"] if value_norm is not None else []
        means = {k: sum(st.get(k, 0.0) for st in steps) / steps_per_round for k in keys}
        relayed = [st for st in steps if "imitation/relay_loss" in st]  # steps whose buffer had a relay label
        means |= {k: float(np.mean([st[k] for st in relayed])) for k in _RELAY_STATS} if relayed else {}
        row = {
            "round": r + 1,
            "episodes": episodes - first_episode,
            "beta": beta,
            "buffer_events": sum(len(buf) for buf in buffers),
            "rollout/success_rate": float(np.mean([st["success_rate"] for st in stats])),
            "rollout/success_by_100": float(np.mean([st["success_by_100"] for st in stats])),
            **means,
            "time/collect_s": t1 - t0,
            "time/update_s": time.perf_counter() - t1,
        }
        log.append(row)
        if on_round is not None:
            on_round(row)
    return episodes - first_episode, log


_RELAY_STATS = ("imitation/relay_loss", "imitation/relay_accuracy")


def _imitation_step(
    model: AMAT,
    opt: torch.optim.Optimizer,
    buffer: DemoBuffer,
    rng: np.random.Generator,
    batch_events: int,
    skip: int | None,
    value_norm: ValueNorm | None,
    relay_weight: float,
    max_grad_norm: float,
) -> dict[str, float]:
    """One cross-entropy step of :func:`dagger` on a uniform batch of ``buffer``'s events, and with
    ``relay_weight`` on a quarter batch of its relay labels (:func:`_relay_batch`); returns its stats."""
    n_classes, device = model.config.n_classes, next(model.parameters()).device
    idx = rng.integers(0, len(buffer), size=min(batch_events, len(buffer)))
    loss, stats = imitation_loss(model, buffer.batch(idx, n_classes, device), skip, value_norm)
    relay = _relay_batch(buffer, rng, max(1, batch_events // 4), n_classes, device) if relay_weight else None
    if relay is not None:
        relay_loss, relay_stats = imitation_loss(model, relay)
        loss = loss + relay_weight * relay_loss
        stats |= dict(zip(_RELAY_STATS, (relay_stats["imitation/loss"], relay_stats["imitation/accuracy"])))
    opt.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(model.parameters(), max_grad_norm)
    opt.step()
    return stats


def _relay_batch(
    buffer: DemoBuffer, rng: np.random.Generator, size: int, n_classes: int, device: torch.device
) -> dict[str, torch.Tensor] | None:
    """``size`` events drawn from those of ``buffer`` with a label the teacher's relay rule chose, only
    those labels scored (the other robots' labels still feed the decoder); None when there is none."""
    if not len(buffer.relay_events):
        return None
    batch = buffer.batch(rng.choice(buffer.relay_events, size), n_classes, device)
    batch["active"] = batch["relay"]
    return batch


def warm_start(
    cfg, model, collector, gen, run_dir, progress: bool, evaluate=None, log_scalars=None, value_norm=None
) -> tuple[float, int]:
    """The DAgger rounds of a training run (``cfg.imitation``: the ``warm_start*`` fields; the run's seed,
    ``optim.max_grad_norm`` and ``loss.gamma``) into ``run_dir/warm_start.csv``, with ``evaluate()`` (a
    dict with success_rate, success_by_100 and their sampled_ forms) after each round if given and
    ``log_scalars(row, step, skip)`` for TensorBoard; returns (the seconds spent, evaluation excluded;
    the episodes played)."""
    imitation = cfg.imitation
    file, writer = open_csv_log(run_dir / "warm_start.csv", WARM_START_METRICS, None, key="round")
    elapsed = 0.0
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(
            total=imitation.warm_start_rounds, desc=f"warm start ({imitation.warm_start})", unit="round"
        )

    def on_round(row: dict) -> None:
        nonlocal elapsed
        elapsed += row["time/collect_s"] + row["time/update_s"]
        row["time/elapsed_min"] = elapsed / 60.0
        if evaluate is not None:
            ev = evaluate()
            row |= {
                f"eval/{k}": ev[k]
                for k in ("success_rate", "success_by_100", "sampled_success_rate", "sampled_success_by_100")
            }
        write_csv_row(writer, file, row)
        if log_scalars is not None:
            log_scalars({f"warm_start/{k}": v for k, v in row.items()}, row["round"], "warm_start/round")
        if bar is not None:
            bar.update(1)
            acc, success = row["imitation/accuracy"], row["rollout/success_rate"]
            bar.set_postfix(acc=f"{acc:.2f}", success=f"{success:.2f}")

    try:
        episodes, _ = dagger(
            model,
            collector,
            imitation.warm_start,
            imitation.warm_start_rounds,
            imitation.warm_start_steps,
            batch_events=imitation.warm_start_batch,
            lr=imitation.warm_start_lr,
            generator=gen,
            seed=cfg.seed,
            max_grad_norm=cfg.optim.max_grad_norm,
            on_round=on_round,
            follow_heading=imitation.warm_start_heading,
            imitate_stay=imitation.warm_start_stay,
            value_norm=value_norm if imitation.warm_start_value else None,
            gamma=cfg.loss.gamma,
            relay_weight=imitation.warm_start_relay,
        )
    finally:
        file.close()
        if bar is not None:
            bar.close()
    return elapsed, episodes
