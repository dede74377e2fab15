"""Asynchronous centralised training of AMAT with PPO (docs/design.md#training): build the parts, then
one loop.

    build: config -> AMAT -> Adam -> value normaliser -> collector (B worlds) [-> checkpoint to resume]
    (warm start: DAgger rounds against a window-projected planner, ``training.imitation``)
    loop:  LR (``ppo.lr_factor``) -> collect one episode per world (``collect``) -> async GAE and
           the batch (``gae``) -> PPO epochs with a target-KL stop (``ppo``) -> log -> evaluate
           -> checkpoint (``catmip_rl.store.checkpoint``)

Everything needed to continue a run exactly is saved atomically in ``RUN_DIR/checkpoints``; the
resolved config is ``RUN_DIR/config.json`` (written once every check has passed and the parts are
built; ``run_dir`` holds the checks and the clean-up of a new run stopped before its first checkpoint);
a run started from other weights (``init_from``) writes where they came from to ``init_from.json``;
metrics go to ``RUN_DIR/metrics.csv`` (per-epoch PPO statistics to ``ppo_epochs.csv``, DAgger rounds to
``warm_start.csv``) and TensorBoard.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from catmip_env.config import EnvConfig
from catmip_rl.amat.model import AMAT
from catmip_rl.amat.pointer import make_model
from catmip_rl.store.checkpoint import load_initial_weights, restore_training, save_training_checkpoint
from catmip_rl.store.files import atomic_write_text
from catmip_rl.training.allocator import keep_freed_memory
from catmip_rl.training.collect import Collector, Rollout
from catmip_rl.training.config import TrainConfig
from catmip_rl.training.gae import ValueNorm, build_batch
from catmip_rl.training.imitation import warm_start
from catmip_rl.training.labelers import PlannerLabeler, RescueLabeler, auxiliary_labeler
from catmip_rl.training.parallel_update import ParallelGradients
from catmip_rl.training.ppo import (
    choose_bf16,
    loss_kwargs,
    lr_factor,
    make_optimizer,
    ppo_update,
    precision_machine,
    set_lr,
)
from catmip_rl.training.run_dir import (
    RunDirLock,
    check_run,
    remove_run_files,
    stopped_note,
)
from catmip_rl.training.run_logs import METRICS, RunLogs, progress_bar, show_progress

__all__ = [
    "train",
    "evaluate_policy",
    "Run",
    "build_run",
    "make_collectors",
    "ppo_iteration",
]


@torch.no_grad()
def evaluate_policy(model: AMAT, collector: Collector, seed: int) -> dict[str, float]:
    """Episodes of ``collector`` (``make_collectors``' evaluator: the training task with evaluation
    activation on a fixed map set): argmax actions (the paper's protocol; success, ticks, decisions,
    stalls) and sampled actions (``sampled_*``, from a generator seeded by ``seed``)."""
    out = dict(collector.collect(model, first_episode=0, deterministic=True).stats)
    gen = torch.Generator().manual_seed(seed)
    sampled = collector.collect(model, first_episode=0, generator=gen).stats
    out |= {f"sampled_{k}": sampled[k] for k in ("success_rate", "success_by_100")}
    return out


@dataclass
class Run:
    """The parts of a training run and where it stands (what a checkpoint saves and restores)."""

    cfg: TrainConfig
    device: torch.device
    model: AMAT
    opt: torch.optim.Optimizer
    value_norm: ValueNorm
    gen: torch.Generator
    iteration: int = 0
    episodes: int = 0
    elapsed: float = 0.0  # seconds of training so far (evaluation excluded): the time budget's clock
    bf16: bool | None = None  # the update's precision, chosen on the first batch (kept on a like machine)
    parallel: ParallelGradients | None = None  # the update's helper processes, started on the first batch
    init_source: dict | None = None  # where a new run's initial weights came from (init_from)
    labeler: RescueLabeler | PlannerLabeler | None = None  # the auxiliary loss's labels (rescue, anchor)
    # make_collectors: the training worlds, taking turns (Collectors, or one Ray collector); the warm
    # start's (none without one, or on resume); the evaluator (None without evaluation)
    collectors: list[Any] = field(default_factory=list)
    dagger: list[Collector] = field(default_factory=list)
    evaluator: Collector | None = None

    def collector_for(self, iteration: int):
        """The collector of PPO iteration ``iteration`` (1, 2, ...): a mixture's worlds take turns."""
        return self.collectors[(iteration - 1) % len(self.collectors)]

    def evaluate(self) -> dict[str, float]:
        """The evaluator's episodes (:func:`evaluate_policy`, sampled actions seeded by ``eval_seed``)."""
        return evaluate_policy(self.model, self.evaluator, self.cfg.eval.eval_seed)

    def checkpoint(self, ckpt_dir: Path) -> None:
        """Save the run as ``ckpt_dir/latest.pt``, then as ``ckpt_dir/iter_NNNNNN.pt`` (its iteration):
        once any snapshot exists, ``latest.pt`` does, so ``--resume`` always has it; a run stopped
        between the two writes the missing snapshot again when it resumes (:meth:`restore_snapshot`)."""
        self.save(ckpt_dir / "latest.pt")
        self.save(ckpt_dir / f"iter_{self.iteration:06d}.pt")

    def restore_snapshot(self, ckpt_dir: Path) -> bool:
        """Write ``iter_NNNNNN.pt`` of the resumed iteration again if it is missing (a run stopped
        after ``latest.pt``, see :meth:`checkpoint`): the same state, since ``latest.pt`` is that iteration's.
        Returns whether it was missing."""
        path = ckpt_dir / f"iter_{self.iteration:06d}.pt"
        if path.exists():
            return False
        self.save(path)
        return True

    def save(self, path: Path) -> None:
        machine = None if self.bf16 is None else precision_machine(self.cfg.device)  # where bf16 was chosen
        save_training_checkpoint(
            path,
            iteration=self.iteration,
            episodes=self.episodes,
            elapsed_s=self.elapsed,
            bf16=self.bf16,
            bf16_machine=machine,
            model=self.model,
            optimizer=self.opt,
            value_norm=self.value_norm,
            generator=self.gen,
            config=self.cfg,
        )

    def out_of_time(self) -> bool:
        """Whether the time budget (``budget_minutes`` of training, evaluation excluded) is spent."""
        budget = self.cfg.optim.budget_minutes
        return bool(budget) and self.elapsed >= 60.0 * budget

    def close(self) -> None:
        if self.cfg.collection.collector == "ray":
            self.collectors[0].close()  # stops the workers, and Ray if this run started it
        if self.parallel is not None:
            self.parallel.close()


def build_run(cfg: TrainConfig, saved: dict | None = None) -> Run:
    """Build a run's parts from ``cfg`` (seeded by ``cfg.seed``), continuing from the training
    checkpoint ``saved`` if given, else starting from ``init_from``'s weights if set."""
    torch.set_num_threads(cfg.threads)
    keep_freed_memory()  # reuse the step's large activations' pages (training.allocator)
    device = torch.device(cfg.device)
    torch.manual_seed(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)
    amat_config = cfg.amat_config()
    model = make_model(amat_config).to(device)
    # the value normaliser stays on the CPU, where the batch is built (gae.build_batch), then moved to device
    run = Run(cfg, device, model, make_optimizer(model, cfg.optim), ValueNorm(), gen)
    if saved is not None:
        machine = precision_machine(cfg.device)  # a saved bf16 choice holds on a like machine only
        run.iteration, run.episodes, run.elapsed, run.bf16 = restore_training(
            saved, model, run.opt, run.value_norm, gen, cfg.optim.precision, machine
        )
    elif cfg.model.init_from:
        run.init_source = load_initial_weights(cfg.model.init_from, model, run.value_norm)
    run.collectors, run.dagger, run.evaluator = make_collectors(cfg, model, resume=saved is not None)
    run.labeler = auxiliary_labeler(cfg.loss, cfg.seed)
    return run


def make_collectors(
    cfg: TrainConfig, model: AMAT, resume: bool = False
) -> tuple[list[Any], list[Collector], Collector | None]:
    """A run's collectors: (the training worlds, which take turns: one, or the mixture's ``worlds``;
    the warm start's, with ``warm_start_worlds`` episodes a round where that is set, else the training
    worlds themselves (none on ``resume``); the evaluator, ``eval_episodes`` of the training task
    with evaluation activation, or None). They play on the CPU wherever ``model`` trains."""
    gamma, evaluation = cfg.loss.gamma, cfg.eval

    def new(env: EnvConfig, n: int, seed: int = cfg.seed) -> Collector:
        return Collector(env, n, seed, gamma, goal_mode=model.config.goals)

    specs = cfg.world_configs()
    if cfg.collection.collector == "ray":  # the same episodes, by Ray workers (adapters/ray_collect.py)
        from catmip_rl.adapters.ray_collect import RayRolloutCollector

        env, _ = specs[0]  # the one world: TrainConfig refuses a mixture with Ray
        train_worlds = [RayRolloutCollector(env, cfg.collection, cfg.seed, gamma, model)]
    else:
        train_worlds = [new(env, n) for env, n in specs]
    dagger = []
    if cfg.imitation.warm_start and not resume:
        n = cfg.imitation.warm_start_worlds
        own = zip(train_worlds, specs)
        dagger = train_worlds if not n else [c if c.num_worlds == n else new(env, n) for c, (env, _) in own]
    evaluator = None
    if evaluation.eval_every:
        evaluator = new(cfg.eval_env_config(), evaluation.eval_episodes, evaluation.eval_seed)
    return train_worlds, dagger, evaluator


def ppo_iteration(run: Run, run_dir: Path) -> tuple[dict[str, float], list[dict[str, float]], Rollout]:
    """One PPO iteration (``run.iteration + 1``): the LR for it, one episode per world, async GAE, the
    update. Returns its metrics row (without evaluation), the per-epoch PPO statistics and the
    rollout it trained on."""
    cfg, it = run.cfg, run.iteration + 1
    optim = cfg.optim
    t0 = time.perf_counter()
    collector = run.collector_for(it)
    rollout = collector.collect(run.model, first_episode=run.episodes, generator=run.gen, labeler=run.labeler)
    run.episodes += collector.num_worlds
    t1 = time.perf_counter()
    n_classes = run.model.config.n_classes
    batch, info = build_batch(rollout, run.value_norm, cfg.loss.gamma, cfg.loss.lam, n_classes, run.device)
    t2 = time.perf_counter()
    if run.bf16 is None:
        fp32 = loss_kwargs(cfg.loss, False)  # the loss that "auto" times in both precisions
        run.bf16, decision = choose_bf16(
            optim.precision, cfg.device, run.model, batch, fp32, optim.micro_batch or 512
        )
        atomic_write_text(run_dir / "precision.json", json.dumps(decision, indent=2))
    if run.parallel is None and optim.update_processes > 1:  # data-parallel gradients (parallel_update.py)
        run.parallel = ParallelGradients(run.model, optim.update_processes, **loss_kwargs(cfg.loss, run.bf16))
    set_lr(run.opt, optim, lr_factor(it, optim, run.elapsed))
    epochs: list[dict[str, float]] = []
    value_only = it <= optim.value_warmup_iterations
    stats = ppo_update(
        run.model,
        run.opt,
        batch,
        optim,
        cfg.loss,
        run.gen,
        parallel=run.parallel,
        epoch_log=epochs,
        value_only=value_only,
        bf16=run.bf16,
    )
    stats["ppo/lr"] = run.opt.param_groups[0]["lr"]
    stats["ppo/bf16"] = float(run.bf16)
    t3 = time.perf_counter()
    run.elapsed += t3 - t0
    run.iteration = it
    row = {"iteration": it, "episodes": run.episodes, **info, **stats}
    row |= {f"rollout/{k}": v for k, v in rollout.stats.items() if f"rollout/{k}" in METRICS}
    if cfg.env.worlds:
        row["rollout/world"] = (it - 1) % len(run.collectors)
    row |= {"time/collect_s": t1 - t0, "time/advantage_s": t2 - t1, "time/update_s": t3 - t2}
    row["time/elapsed_min"] = run.elapsed / 60.0
    return row, epochs, rollout


def _write_run_files(run: Run, run_dir: Path) -> None:
    """``run_dir/config.json`` and, for a run started from other weights, ``init_from.json``."""
    run_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(run_dir / "config.json", run.cfg.to_json())
    if run.init_source is not None:  # the weights' provenance: file, iteration, training minutes
        atomic_write_text(run_dir / "init_from.json", json.dumps(run.init_source, indent=2))


def train(cfg: TrainConfig, run_dir: str | Path, resume: bool = False, progress: bool = True) -> AMAT:
    """Run (or continue, with ``resume``) a training run in ``run_dir``; returns the model. The run holds
    ``run_dir`` while it lives (``run_dir.RunDirLock``: a second writer is refused); refusals
    (``run_dir.check_run``) come before anything is built or written."""
    run_dir = Path(run_dir)
    ckpt_dir = run_dir / "checkpoints"
    latest = ckpt_dir / "latest.pt"
    lock = RunDirLock(run_dir).acquire()
    try:
        run = build_run(cfg, check_run(cfg, run_dir, resume))
    except BaseException:
        lock.release(undo=True)  # a refused run leaves nothing behind
        raise
    created = lock.created  # a new run stopped before its first checkpoint removes its files
    logs = RunLogs()
    finished = False

    try:
        _write_run_files(run, run_dir)
        logs.open(run_dir, run.iteration if resume else None)
        if resume and run.restore_snapshot(ckpt_dir):
            print(f"catmip train: iter_{run.iteration:06d}.pt was missing: written again from latest.pt")

        # -- imitation warm start (DAgger against a window-projected planner), once, before PPO -------
        # (every checkpoint, iter_000000.pt included, is written after it: a resumed run never repeats it)
        # its training time and episodes count as the run's (PPO's maps follow its maps)
        if cfg.imitation.warm_start and not resume:
            evaluate = run.evaluate if run.evaluator else None  # after each round
            run.elapsed, run.episodes = warm_start(
                cfg, run.model, run.dagger, run.gen, run_dir, progress, evaluate, logs.scalars, run.value_norm
            )
            run.checkpoint(ckpt_dir)
        iterations, evaluation = cfg.optim.iterations, cfg.eval
        bar = progress_bar(iterations, run.iteration, progress)

        # -- the loop ------------------------------------------------------------------------------------
        while run.iteration < iterations:
            if run.out_of_time():
                break
            t0 = time.perf_counter()
            row, epochs, _ = ppo_iteration(run, run_dir)
            it = run.iteration
            last = it == iterations or run.out_of_time()
            if evaluation.eval_every and (it % evaluation.eval_every == 0 or last):
                row |= {f"eval/{k}": v for k, v in run.evaluate().items() if f"eval/{k}" in METRICS}
            row["time/iteration_s"] = time.perf_counter() - t0
            if bar is not None:
                show_progress(bar, row)
            logs.write(it, row, epochs)
            if cfg.checkpoint_every and (it % cfg.checkpoint_every == 0 or last):
                run.checkpoint(ckpt_dir)
        if bar is not None:
            bar.close()
        finished = True
    except BaseException as err:  # an error or Ctrl-C: the message says what is left of the run
        err.add_note(stopped_note(run_dir, resume, created))
        raise
    finally:
        logs.close()
        run.close()
        nothing_to_resume = not (finished or resume or latest.exists())
        if nothing_to_resume:  # leave the dir as it was
            remove_run_files(run_dir, created)
        lock.release(undo=nothing_to_resume)
    return run.model
