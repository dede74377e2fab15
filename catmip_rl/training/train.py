"""Asynchronous centralised training of AMAT with PPO (docs/design.md#training) — the whole loop in one place.

    build: config -> collector (B worlds) -> AMAT -> Adam -> value normaliser
    (warm start: DAgger rounds against a window-projected planner, catmip_rl.training.imitation)
    loop:  LR (linear decay over the iterations or the time budget) -> collect one episode per world
           -> async GAE -> PPO epochs (target-KL stop) -> log -> evaluate -> checkpoint

Everything needed to continue a run exactly (model, optimiser, value normaliser, the sampling
generator's state, the iteration, the training time so far that a time budget's LR schedule reads) is
saved atomically in ``RUN_DIR/checkpoints``; the resolved config is ``RUN_DIR/config.json`` (written
once every check has passed and the parts are built: a refused run leaves nothing behind, and a new run
stopped by an error or Ctrl-C before its first checkpoint removes what it wrote, so that its run dir can
be used again); metrics go to ``RUN_DIR/metrics.csv`` (per-epoch PPO statistics to ``ppo_epochs.csv``,
DAgger rounds to ``warm_start.csv``) and TensorBoard.
"""

from __future__ import annotations

import json
import math
import shutil
import time
from pathlib import Path

import numpy as np
import torch

from catmip_rl.amat.model import AMAT
from catmip_rl.checkpoint import atomic_torch_save, resume_checkpoint
from catmip_rl.files import atomic_write_text, check_new_dir, open_csv_log, write_csv_row
from catmip_rl.training.collect import Collector, Rollout
from catmip_rl.training.config import TrainConfig
from catmip_rl.training.gae import async_gae
from catmip_rl.training.imitation import warm_start
from catmip_rl.training.memory import keep_freed_memory
from catmip_rl.training.parallel_update import ParallelGradients
from catmip_rl.training.ppo import SampleBatch, ValueNorm, accumulate_gradients
from catmip_rl.training.precision import choose_bf16, use_bf16

__all__ = [
    "train",
    "build_batch",
    "make_optimizer",
    "ppo_update",
    "lr_factor",
    "loss_kwargs",
    "evaluate_policy",
    "METRICS",
]

METRICS = [
    "iteration", "episodes", "samples",
    "rollout/success_rate", "rollout/success_by_100", "rollout/rescue_tick", "rollout/target_found_rate",
    "rollout/target_found_tick",
    "rollout/explored_fraction", "rollout/episode_ticks", "rollout/return_rescuer", "rollout/return_explorer",
    "rollout/decisions_per_episode", "rollout/stalls_per_episode", "rollout/stall_fraction_rescuer",
    "rollout/stall_fraction_explorer",
    "loss/policy", "loss/value", "loss/entropy",
    "ppo/approx_kl", "ppo/clip_fraction", "ppo/grad_norm", "ppo/lr", "ppo/epochs", "ppo/early_stop",
    "ppo/bf16",
    "eval/success_rate", "eval/success_by_100", "eval/rescue_tick", "eval/target_found_tick",
    "eval/explored_fraction", "eval/decisions_per_episode", "eval/stalls_per_episode",
    "eval/stall_fraction_rescuer", "eval/stall_fraction_explorer",
    "eval/sampled_success_rate", "eval/sampled_success_by_100",
    "time/collect_s", "time/advantage_s", "time/update_s", "time/iteration_s", "time/elapsed_min",
]  # fmt: skip
EPOCH_METRICS = ["iteration", "epoch", "loss/policy", "loss/value", "loss/entropy", "ppo/approx_kl",
                 "ppo/clip_fraction"]  # fmt: skip
EVAL_KEYS = ("success_rate", "success_by_100", "rescue_tick", "target_found_tick", "explored_fraction",
             "decisions_per_episode", "stalls_per_episode", "stall_fraction_rescuer",
             "stall_fraction_explorer")  # fmt: skip


def build_batch(r: Rollout, value_norm: ValueNorm, gamma: float, lam: float, n_classes: int,
                device: torch.device) -> tuple[SampleBatch, dict[str, float]]:  # fmt: skip
    """Async GAE on a rollout and the flat sample batch (rows = valid events)."""
    values = value_norm.denormalize(torch.from_numpy(r.value).double()).numpy()
    adv, ret, trainable = async_gae(
        r.active,
        r.valid,
        values,
        r.ma_return,
        r.ma_ticks.astype(np.int64),
        r.final_return,
        r.terminated,
        gamma,
        lam,
    )
    rows = r.valid
    ret_t = torch.from_numpy(ret[rows]).float()
    train_t = torch.from_numpy(trainable[rows])
    if train_t.any():
        value_norm.update(ret_t[train_t])
    adv_t = torch.from_numpy(adv[rows]).float()
    if train_t.sum() > 1:
        a = adv_t[train_t]
        adv_t = (adv_t - a.mean()) / (a.std() + 1e-8)
    batch = SampleBatch(
        global_map=torch.from_numpy(r.global_map[rows]),
        local_map=torch.from_numpy(r.local_map[rows]),
        agent_class=torch.nn.functional.one_hot(torch.from_numpy(r.agent_class[rows]), n_classes).float(),
        action_mask=torch.from_numpy(r.action_mask[rows]),
        order=torch.from_numpy(r.order[rows]),
        action=torch.from_numpy(r.action[rows]),
        log_prob=torch.from_numpy(r.log_prob[rows]),
        value=torch.from_numpy(r.value[rows]),
        advantage=adv_t,
        target=value_norm.normalize(ret_t),
        trainable=train_t,
    ).to(device)
    return batch, {"samples": float(train_t.sum())}


def make_optimizer(model: AMAT, cfg: TrainConfig) -> torch.optim.Adam:
    """Adam with the config's lr and eps, fused (one kernel for all parameters: ~6x faster a step on CPU
    than the per-parameter loop, the same arithmetic)."""
    return torch.optim.Adam(model.parameters(), lr=cfg.lr, eps=cfg.adam_eps, fused=True)


def loss_kwargs(cfg: TrainConfig, bf16: bool | None = None) -> dict[str, float]:
    """The config's ``accumulate_gradients`` arguments: ``ppo_loss`` coefficients and bf16 autocast
    (``bf16``, or ``cfg.precision`` resolved by the CPU's flags; ``train`` measures "auto")."""
    return {
        "clip": cfg.clip, "value_clip": cfg.value_clip, "huber_delta": cfg.huber_delta,
        "entropy_coef": cfg.entropy_coef, "value_coef": cfg.value_coef,
        "bf16": use_bf16(cfg.precision, cfg.device) if bf16 is None else bf16,
    }  # fmt: skip


def ppo_update(
    model: AMAT,
    opt: torch.optim.Optimizer,
    batch: SampleBatch,
    cfg: TrainConfig,
    gen: torch.Generator,
    parallel: ParallelGradients | None = None,
    epoch_log: list[dict[str, float]] | None = None,
    value_only: bool = False,
    bf16: bool | None = None,
) -> dict[str, float]:
    """Up to ``cfg.epochs`` passes over ``cfg.minibatches`` minibatches of ``batch``, one Adam step each;
    each minibatch's gradient is accumulated over micro-batches of ``cfg.micro_batch`` events, by this
    process or, with ``parallel``, shared with its helper processes. With ``cfg.target_kl`` the epochs
    stop at the first minibatch whose approx-KL (before its step) exceeds it, without stepping.

    Returns the last minibatch's loss parts and gradient norm, ``ppo/epochs`` (epochs run, fractional
    when stopped inside one) and ``ppo/early_stop``; ``epoch_log`` receives one dict per epoch (its
    minibatches' mean loss parts, approx-KL and clip fraction). ``value_only`` steps the value head
    alone (the value warm-up after an imitation warm start: the policy is left as it is). ``bf16``
    overrides the precision the config resolves to (see :func:`loss_kwargs`)."""
    model.train()
    params = [p for p in model.parameters() if p.requires_grad]
    frozen = [p for n, p in model.named_parameters() if not n.startswith("value_head.")] if value_only else []
    stats: dict[str, float] = {}
    if parallel is not None:
        parallel.set_batch(batch)
    steps, stopped = 0, False
    for epoch in range(cfg.epochs):
        perm = torch.randperm(len(batch), generator=gen) if cfg.minibatches > 1 else torch.arange(len(batch))
        epoch_sums: dict[str, float] = {}
        seen = 0
        for idx in perm.chunk(cfg.minibatches):
            idx = idx.to(batch.action.device)
            count = batch.trainable[idx].sum().clamp_min(1).float()
            opt.zero_grad(set_to_none=True)
            parts = list(idx.split(cfg.micro_batch)) if cfg.micro_batch else [idx]
            if parallel is None:
                sums = accumulate_gradients(model, batch, parts, count, **loss_kwargs(cfg, bf16))
            else:
                sums = parallel.backward(model, parts, count)
            seen += 1
            for k, v in sums.items():
                epoch_sums[k] = epoch_sums.get(k, 0.0) + v
            if cfg.target_kl and sums["ppo/approx_kl"] > cfg.target_kl:
                stopped = True
                stats = sums | {"ppo/grad_norm": float("nan")}
                break
            for p in frozen:
                p.grad = None  # Adam skips parameters without a gradient
            grad_norm = torch.nn.utils.clip_grad_norm_(params, cfg.max_grad_norm)
            opt.step()
            steps += 1
            stats = sums | {"ppo/grad_norm": float(grad_norm)}
        if epoch_log is not None:
            epoch_log.append({"epoch": epoch + 1} | {k: v / seen for k, v in epoch_sums.items()})
        if stopped:
            break
    opt.zero_grad(set_to_none=True)
    return stats | {"ppo/epochs": steps / cfg.minibatches, "ppo/early_stop": float(stopped)}


def lr_factor(iteration: int, cfg: TrainConfig, elapsed_s: float) -> float:
    """Linear decay to 0 over the run: over ``cfg.iterations``, or over ``cfg.budget_minutes`` of
    training if that runs out first (``iteration`` counts from 1; ``elapsed_s`` before it)."""
    progress = (iteration - 1) / cfg.iterations
    if cfg.budget_minutes:
        progress = max(progress, elapsed_s / (60.0 * cfg.budget_minutes))
    return max(0.0, 1.0 - progress)


@torch.no_grad()
def evaluate_policy(
    model: AMAT, cfg: TrainConfig, device: torch.device, collector: Collector | None = None
) -> dict[str, float]:
    """Episodes of the training task with evaluation activation on a fixed map set: argmax actions
    (the paper's protocol; success, ticks, decisions, stalls) and sampled actions (``sampled_*``, from
    a generator seeded by ``cfg.eval_seed``). Pass the ``collector`` of a previous call to reuse it."""
    if collector is None:
        collector = Collector(cfg.eval_env_config(), cfg.eval_episodes, cfg.eval_seed, cfg.gamma, str(device))
    out = dict(collector.collect(model, first_episode=0, deterministic=True).stats)
    gen = torch.Generator(device=device).manual_seed(cfg.eval_seed)
    sampled = collector.collect(model, first_episode=0, generator=gen).stats
    out |= {f"sampled_{k}": sampled[k] for k in ("success_rate", "success_by_100")}
    return out


def _save(
    path: Path, it: int, episodes: int, elapsed_s: float, bf16, model, opt, value_norm, gen, cfg
) -> None:
    atomic_torch_save(
        {
            "iteration": it,
            "episodes": episodes,
            "elapsed_s": elapsed_s,
            "bf16": bf16,  # the precision "auto" chose (None: not chosen yet); a resumed run keeps it
            "model": model.state_dict(),
            "amat_config": cfg.amat_config().__dict__,
            "optimizer": opt.state_dict(),
            "value_norm": value_norm.state_dict(),
            "generator": gen.get_state(),
            "torch_rng": torch.get_rng_state(),
            "config": cfg.to_json(),
        },
        path,
    )


def _check_run(cfg: TrainConfig, run_dir: Path, resume: bool) -> dict | None:
    """Every refusal, before anything is built or written: the checkpoint to continue (``resume``) must
    be readable and of the same model and task; a new run needs a new or empty run dir. Also the
    device and, for ``collector="ray"``, the ray package. Returns the checkpoint (None for a new run)."""
    saved = None
    if resume:
        saved = resume_checkpoint(run_dir)
        saved_cfg = TrainConfig.from_json(saved["config"])
        if saved_cfg.amat_config() != cfg.amat_config() or saved_cfg.env_config() != cfg.env_config():
            raise ValueError(
                f"--resume: the checkpoint in {run_dir} was trained with another model or task "
                f"({saved_cfg.amat_config()} on {saved_cfg.env_preset}); start a new run dir instead"
            )
    elif (run_dir / "checkpoints" / "latest.pt").exists():
        raise FileExistsError(
            f"{run_dir} already holds a run; pass --resume to continue it or pick a new dir"
        )
    else:
        check_new_dir(run_dir, "run dir", advice="pick a new run dir (or empty this one)")
    try:
        cuda = torch.device(cfg.device).type == "cuda"
    except RuntimeError:
        raise ValueError(f"device must be cpu, cuda or cuda:N, got {cfg.device!r}") from None
    if cuda and not torch.cuda.is_available():
        raise ValueError(f"device {cfg.device!r} requested but torch sees no CUDA device")
    if cfg.collector == "ray":
        from catmip_rl.adapters.ray_collect import import_ray

        import_ray()  # RuntimeError naming the extra to install
    return saved


def _tensorboard(run_dir: Path):
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:  # tensorboard comes with the rl extra
        return None
    return SummaryWriter(str(run_dir / "tensorboard"))


def train(cfg: TrainConfig, run_dir: str | Path, resume: bool = False, progress: bool = True) -> AMAT:
    """Run (or continue, with ``resume``) a training run in ``run_dir``; returns the model. Refusals
    (see ``_check_run``) come before anything is built or written."""
    run_dir = Path(run_dir)
    ckpt_dir = run_dir / "checkpoints"
    latest = ckpt_dir / "latest.pt"
    saved = _check_run(cfg, run_dir, resume)

    # -- build the parts -------------------------------------------------------------------------------
    torch.set_num_threads(cfg.threads)
    keep_freed_memory()  # reuse the step's large activations' pages (catmip_rl.training.memory)
    device = torch.device(cfg.device)
    torch.manual_seed(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)
    env_cfg = cfg.env_config()
    model = AMAT(cfg.amat_config()).to(device)
    opt = make_optimizer(model, cfg)
    value_norm = ValueNorm().to(device)
    evaluator = None
    if cfg.eval_every:
        evaluator = Collector(cfg.eval_env_config(), cfg.eval_episodes, cfg.eval_seed, cfg.gamma, str(device))
    start, episodes, elapsed = 0, 0, 0.0  # elapsed: seconds of training so far (evaluation excluded)
    chosen_bf16 = None
    if resume:
        model.load_state_dict(saved["model"])
        opt.load_state_dict(saved["optimizer"])
        value_norm.load_state_dict(saved["value_norm"])
        gen.set_state(saved["generator"])
        torch.set_rng_state(saved["torch_rng"])
        start, episodes, elapsed = saved["iteration"], saved["episodes"], saved.get("elapsed_s", 0.0)
        same_precision = TrainConfig.from_json(saved["config"]).precision == cfg.precision
        chosen_bf16 = saved.get("bf16") if same_precision else None
    if (
        cfg.collector == "ray"
    ):  # the same episodes, collected by Ray workers (catmip_rl/adapters/ray_collect.py)
        from catmip_rl.adapters.ray_collect import RayRolloutCollector

        collector = RayRolloutCollector(cfg, model)
    else:
        collector = Collector(env_cfg, cfg.num_worlds, cfg.seed, cfg.gamma, str(device))
    parallel, bf16 = None, chosen_bf16  # set at the first PPO batch (bf16 "auto" measures on it), once a run
    created = _first_missing(run_dir)  # a new run stopped before its first checkpoint removes its files
    csv_file = epoch_file = tb = None
    finished = False

    def save(it: int) -> None:
        _save(latest, it, episodes, elapsed, bf16, model, opt, value_norm, gen, cfg)
        _save(ckpt_dir / f"iter_{it:06d}.pt", it, episodes, elapsed, bf16, model, opt, value_norm, gen, cfg)

    def log_scalars(row: dict, step: int, skip: str) -> None:
        if tb is not None:
            for k, v in row.items():
                if k != skip and isinstance(v, (int, float)) and not math.isnan(v):
                    tb.add_scalar(k, v, step)

    try:
        run_dir.mkdir(parents=True, exist_ok=True)
        atomic_write_text(run_dir / "config.json", cfg.to_json())
        csv_file, csv_writer = open_csv_log(run_dir / "metrics.csv", METRICS, start if resume else None)
        epoch_file, epoch_writer = open_csv_log(
            run_dir / "ppo_epochs.csv", EPOCH_METRICS, start if resume else None
        )
        tb = _tensorboard(run_dir)

        # -- imitation warm start (DAgger against a window-projected planner), once, before PPO -------
        # (every checkpoint, iter_000000.pt included, is written after it: a resumed run never repeats it)
        if cfg.warm_start and not resume:
            evaluate = (lambda: evaluate_policy(model, cfg, device, evaluator)) if evaluator else None
            elapsed = warm_start(cfg, model, collector, gen, run_dir, progress, evaluate, log_scalars)
            episodes = cfg.warm_start_rounds * cfg.num_worlds
            save(0)
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=cfg.iterations, initial=start, desc="train", unit="it")

        # -- the loop ------------------------------------------------------------------------------------
        for it in range(start + 1, cfg.iterations + 1):
            if cfg.budget_minutes and elapsed >= 60.0 * cfg.budget_minutes:
                break
            t0 = time.perf_counter()
            for group in opt.param_groups:
                group["lr"] = cfg.lr * lr_factor(it, cfg, elapsed)
            rollout = collector.collect(model, first_episode=episodes, generator=gen)
            episodes += cfg.num_worlds
            t1 = time.perf_counter()
            batch, info = build_batch(rollout, value_norm, cfg.gamma, cfg.lam, env_cfg.num_classes, device)
            t2 = time.perf_counter()
            if bf16 is None:
                bf16, decision = choose_bf16(
                    cfg.precision, cfg.device, model, batch, loss_kwargs(cfg, False), cfg.micro_batch or 512
                )
                atomic_write_text(run_dir / "precision.json", json.dumps(decision, indent=2))
            if parallel is None and cfg.update_processes > 1:  # data-parallel gradients (parallel_update.py)
                parallel = ParallelGradients(model, cfg.update_processes, **loss_kwargs(cfg, bf16))
            epochs: list[dict[str, float]] = []
            value_only = it <= cfg.value_warmup_iterations
            stats = ppo_update(model, opt, batch, cfg, gen, parallel, epochs, value_only, bf16)
            stats["ppo/lr"] = opt.param_groups[0]["lr"]
            stats["ppo/bf16"] = float(bf16)
            t3 = time.perf_counter()
            elapsed += t3 - t0
            row = {"iteration": it, "episodes": episodes, "samples": info["samples"], **stats}
            row |= {f"rollout/{k}": v for k, v in rollout.stats.items() if f"rollout/{k}" in METRICS}
            row |= {"time/collect_s": t1 - t0, "time/advantage_s": t2 - t1, "time/update_s": t3 - t2}
            row["time/elapsed_min"] = elapsed / 60.0
            last = it == cfg.iterations or (cfg.budget_minutes and elapsed >= 60.0 * cfg.budget_minutes)
            if cfg.eval_every and (it % cfg.eval_every == 0 or last):
                ev = evaluate_policy(model, cfg, device, evaluator)
                row |= {f"eval/{k}": v for k, v in ev.items() if f"eval/{k}" in METRICS}
            row["time/iteration_s"] = time.perf_counter() - t0
            write_csv_row(csv_writer, csv_file, row)
            for e in epochs:
                write_csv_row(epoch_writer, epoch_file, {"iteration": it} | e)
            log_scalars(row, it, "iteration")
            if cfg.checkpoint_every and (it % cfg.checkpoint_every == 0 or last):
                save(it)
            if bar is not None:
                bar.update(1)
                bar.set_postfix(
                    success=f"{row.get('rollout/success_rate', 0):.2f}", kl=f"{stats['ppo/approx_kl']:.4f}",
                    t=f"{row['time/iteration_s']:.1f}s",
                )  # fmt: skip
        if bar is not None:
            bar.close()
        finished = True
    except BaseException as err:  # an error or Ctrl-C: the message says what is left of the run
        err.add_note(_stopped_note(run_dir, resume, created))
        raise
    finally:
        for log in (csv_file, epoch_file, tb):
            if log is not None:
                log.close()
        if cfg.collector == "ray":
            collector.close()  # stops the workers, and Ray if this run started it
        if parallel is not None:
            parallel.close()
        if not (finished or resume or latest.exists()):  # nothing to resume: leave the dir as it was
            _remove_run_files(run_dir, created)
    return model


def _first_missing(path: Path) -> Path | None:
    """The outermost folder of ``path`` (itself included) that does not exist yet: what ``mkdir(parents=
    True)`` creates; None if ``path`` exists."""
    missing = None
    for p in (path, *path.parents):
        if p.exists():
            break
        missing = p
    return missing


def _remove_run_files(run_dir: Path, created: Path | None) -> None:
    """Undo a new run that stopped before its first checkpoint: remove the folders it created, or (its
    run dir was empty before, ``_check_run``) everything it wrote in the run dir."""
    if created is not None:
        shutil.rmtree(created, ignore_errors=True)
        return
    for entry in run_dir.iterdir():
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry, ignore_errors=True)
        else:
            entry.unlink(missing_ok=True)


def _stopped_note(run_dir: Path, resume: bool, created: Path | None) -> str:
    """What a stopped run leaves, for the one-line message (added to the exception as a note)."""
    if resume or (run_dir / "checkpoints" / "latest.pt").exists():
        return f"its checkpoints are kept: continue with catmip train --run-dir {run_dir} --resume"
    what = "removed" if created is not None else "emptied"
    return f"stopped before its first checkpoint, so {run_dir} was {what} (nothing to resume; start it again)"
