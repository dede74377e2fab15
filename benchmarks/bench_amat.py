"""AMAT speed: batch-1 decision latency, batched acting throughput, training-step throughput.

    python benchmarks/bench_amat.py [--repeats 200] [--out benchmarks/results/amat.json]

* latency — one decision at batch 1 on one thread: embed every robot, encode, decode the active
  robots autoregressively (argmax). N = 2, 3, 6 robots on the 15, 20, 32 maps of Tasks 1-3 (presets
  task1-3, real observations after 30 random decision events), with all robots active (the joint
  decision at t = 0) and with one active robot (a typical asynchronous event); also the split embed /
  encode / decode of the torch path, and the numba path
  ``catmip_rl.amat.onboard.fast_amat.FastAmat`` on the same observations and on random dense maps (its
  worst case). Median of ``--repeats``.
* acting — batched decisions (B = 64, 1024 worlds of Task 2, every robot active), one thread,
  agent-decisions per second.
* training — one PPO step (``ppo_loss``: embed, encode, teacher-forced scoring of the trainable robots;
  backward; grad-norm clip; fused Adam) on batches of decision events drawn from Task-2 episodes (real
  maps, uint8 as the collector stores them, so the global CNN takes its sparse path): 256 events, and
  the paper recipe's micro-batch (512 events, ``TrainConfig.micro_batch``: the unit of every forward and
  backward pass of a training update). Two threads, agent-samples (robot tokens) per second, fp32 (and
  CPU bf16 autocast on the smallest batch), with the CPU steal time of the measurement (the share of
  the machine the hypervisor gave to other guests: this VM's speed varies by 10-30 % with it).

Writes JSON and a PNG next to it.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from common import cpu_times, env_observation, steal_percent, write_json

from catmip_env.config import PRESETS, make_config
from catmip_env.engines.events import EventEngine, random_valid_actions
from catmip_env.play import play
from catmip_rl.amat.model import AMAT, decision_order
from catmip_rl.amat.onboard.fast_amat import FastAmat
from catmip_rl.training.allocator import keep_freed_memory
from catmip_rl.training.gae import SampleBatch
from catmip_rl.training.parallel_update import ParallelGradients
from catmip_rl.training.ppo import loss_kwargs, make_optimizer, native_bf16, ppo_loss
from catmip_rl.training.presets import make_train_config

TOKEN_INPUTS = ("global_map", "local_map", "agent_class")
TASKS = ((2, 15, "task1"), (3, 20, "task2"), (6, 32, "task3"))  # (robots, map side, preset) of Tasks 1-3


def _obs(b: int, n: int, s: int, seed: int = 0) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return {
        "global_map": torch.randint(0, 5, (b, n, 7, s, s), generator=g, dtype=torch.uint8),
        "local_map": torch.randint(0, 5, (b, n, 6, 7, 7), generator=g, dtype=torch.uint8),
        "agent_class": F.one_hot(torch.randint(0, 2, (b, n), generator=g), 2).float(),
    }


def _times_ms(fn, repeats: int, warmup: int = 10) -> list[float]:
    """Sorted wall-clock milliseconds of ``repeats`` calls after ``warmup`` calls."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(1000 * (time.perf_counter() - t0))
    return sorted(times)


def _median_ms(fn, repeats: int, warmup: int = 10) -> float:
    return statistics.median(_times_ms(fn, repeats, warmup))


def bench_latency(model: AMAT, repeats: int) -> list[dict]:
    torch.set_num_threads(1)
    # FastAmat's kernels are serial: one thread. (numba.set_num_threads would start numba's OpenMP pool,
    # which makes every torch op in the process ~50x slower: two OpenMP runtimes competing.)
    fast = FastAmat.from_model(model)
    rows = []
    for n, s, preset in TASKS:
        x = {k: v for k, v in env_observation(PRESETS[preset], events=30).items() if k in TOKEN_INPUTS}
        obs = {k: torch.from_numpy(v)[None] for k, v in x.items()}
        rnd = {k: v[0].numpy() for k, v in _obs(1, n, s).items()}
        mask = torch.ones(1, n, model.config.num_actions, dtype=torch.bool)
        for n_active in (n, 1):
            active = torch.zeros(1, n, dtype=torch.bool)
            active[0, :n_active] = True
            mask_np, active_np = mask[0].numpy(), active[0].numpy()
            order = decision_order(active)
            with torch.inference_mode():
                tokens = model.embed(obs)
                rep, _ = model.encode(tokens)

                def decide():
                    r, _ = model.encode(model.embed(obs))
                    return model.decode_autoregressive(
                        r, mask, decision_order(active), active, obs["agent_class"], deterministic=True
                    )

                row = {
                    "robots": n,
                    "map": s,
                    "active": n_active,
                    "decision_ms": _median_ms(decide, repeats),
                    "embed_ms": _median_ms(lambda: model.embed(obs), repeats),
                    "encode_ms": _median_ms(lambda: model.encode(tokens), repeats),
                    "decode_ms": _median_ms(
                        lambda: model.decode_autoregressive(
                            rep, mask, order, active, obs["agent_class"], deterministic=True
                        ),
                        repeats,
                    ),
                    "fast_decision_ms": _median_ms(
                        lambda: fast.decide(**x, action_mask=mask_np, active=active_np), repeats
                    ),
                    "fast_random_maps_ms": _median_ms(
                        lambda: fast.decide(**rnd, action_mask=mask_np, active=active_np),
                        max(repeats // 10, 5),
                    ),
                }
            rows.append(row)
            parts = ", ".join(f"{k[:-3]} {row[k]:.2f}" for k in ("embed_ms", "encode_ms", "decode_ms"))
            print(
                f"latency N={n} S={s} active={n_active}: torch {row['decision_ms']:.2f} ms ({parts}); "
                f"FastAmat {row['fast_decision_ms']:.2f} ms (random maps {row['fast_random_maps_ms']:.2f})"
            )
    return rows


def bench_acting(model: AMAT, batches=(64, 1024)) -> list[dict]:
    torch.set_num_threads(1)
    rows = []
    n, s = 3, 20
    for b in batches:
        obs = _obs(b, n, s)
        mask = torch.ones(b, n, model.config.num_actions, dtype=torch.bool)
        active = torch.ones(b, n, dtype=torch.bool)

        def act():
            with torch.inference_mode():
                rep, _ = model.encode(model.embed(obs))
                model.decode_autoregressive(rep, mask, decision_order(active), active, obs["agent_class"])

        ms = _median_ms(act, repeats=5 if b >= 1024 else 20, warmup=2)
        rows.append(
            {"worlds": b, "robots": n, "map": s, "ms": ms, "agent_decisions_per_s": b * n / ms * 1000}
        )
        print(f"acting B={b}: {ms:.1f} ms per batch, {b * n / ms * 1000:,.0f} agent-decisions/s")
    return rows


def task2_training_batch(events: int, seed: int = 0) -> SampleBatch:
    """``events`` decision events drawn uniformly from one episode in each of 64 Task-2 worlds (20x20,
    rescuer + 2 explorers, training activation (2, 5)) played with random valid goals: real maps as a
    training batch holds them, from the first event to the last. Advantages and targets are random."""
    eng = EventEngine(make_config("task2", activation=(2, 5)), 64, seed)
    eng.reset()
    rng = np.random.default_rng(seed)
    rows: dict[str, list] = {k: [] for k in ("global_map", "local_map", "cls", "mask", "active", "action")}

    def random_goals(e: EventEngine) -> np.ndarray:  # the policy, keeping what it saw and chose
        live = np.flatnonzero(~e.state.done)
        actions = random_valid_actions(e.masks, rng)
        seen = (e.obs_global, e.obs_local, e.state.cls, e.masks, e.active, actions)
        for key, value in zip(rows, seen):
            rows[key].append(np.array(value[live]))
        return actions

    play(eng, random_goals)
    data = {k: torch.from_numpy(np.concatenate(v)) for k, v in rows.items()}
    pick = torch.from_numpy(rng.choice(len(data["action"]), events, replace=False))
    data = {k: v[pick] for k, v in data.items()}
    active = data["active"].bool()
    g = torch.Generator().manual_seed(seed)
    m, n = active.shape
    return SampleBatch(
        global_map=data["global_map"],
        local_map=data["local_map"],
        agent_class=F.one_hot(data["cls"].long(), 2).float(),
        action_mask=data["mask"].bool(),
        order=decision_order(active),
        action=data["action"].long(),
        log_prob=-torch.rand(m, n, generator=g),
        value=torch.randn(m, n, generator=g),
        advantage=torch.randn(m, n, generator=g),
        target=torch.randn(m, n, generator=g),
        trainable=active,
    )


def bench_training(model: AMAT, batch: SampleBatch, bf16: bool, steps: int, processes: int = 1) -> dict:
    """One PPO minibatch step as training runs it: ``ppo_loss`` forward, backward, grad-norm clip and
    fused Adam (``training.ppo.make_optimizer``). One process on two threads, or ``processes``
    single-threaded processes (``training.parallel_update``), each with one micro-batch of ``batch``'s
    events (so the step covers ``processes`` x as many events)."""
    torch.set_num_threads(2)
    keep_freed_memory()  # as catmip_rl.training.train.train does
    cfg = make_train_config("paper")
    opt = make_optimizer(model, cfg.optim)
    m, n = batch.action.shape
    parallel = None
    if processes > 1:
        parallel = ParallelGradients(model, processes, **loss_kwargs(cfg.loss))
        batch = batch.map(lambda v: torch.cat([v] * processes))
        parallel.set_batch(batch)
        parts = list(torch.arange(m * processes).chunk(processes))
        count = batch.trainable.sum().clamp_min(1).float()

    def step():
        opt.zero_grad(set_to_none=True)
        if parallel is not None:
            parallel.backward(model, parts, count)
        else:
            with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
                loss, _ = ppo_loss(model, batch)
            loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 10.0)
        opt.step()

    try:
        for _ in range(2):
            step()
        before = cpu_times()
        times = _times_ms(step, repeats=steps, warmup=0)
        steal = steal_percent(before, cpu_times())
    finally:
        if parallel is not None:
            parallel.close()
    ms = statistics.median(times)
    samples = m * n * processes
    row = {
        "worlds": m,
        "robots": n,
        "map": batch.global_map.shape[-1],
        "batch": "task2 rollout events",
        "precision": "bf16-autocast" if bf16 else "fp32",
        "processes": processes,
        "threads_per_process": 2 if processes == 1 else 1,
        "ms_per_step": ms,
        "best_ms_per_step": times[0],
        "agent_samples_per_s": samples / ms * 1000,  # median step
        "best_agent_samples_per_s": samples / times[0] * 1000,
        "cpu_steal_pct": steal,
    }
    rate, best = row["agent_samples_per_s"], row["best_agent_samples_per_s"]
    stolen = "" if steal is None else f", CPU steal {steal:.0f} %"
    how = "1 process x 2 threads" if processes == 1 else f"{processes} processes x 1 thread"
    print(
        f"training {row['precision']:>13} batch {m}x{n}, {how}: {ms:.0f} ms/step (median), "
        f"{rate:,.0f} agent-samples/s (best step {best:,.0f}/s{stolen})"
    )
    return row


def plot(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    lat = results["latency"]
    labels = [f"N={r['robots']}\nS={r['map']}\n{r['active']} active" for r in lat]
    parts = ("embed_ms", "encode_ms", "decode_ms")
    bottom = [0.0] * len(lat)
    for key in parts:
        vals = [r[key] for r in lat]
        axes[0].bar(labels, vals, bottom=bottom, label="torch " + key.replace("_ms", ""))
        bottom = [a + b for a, b in zip(bottom, vals)]
    axes[0].scatter(
        labels, [r["decision_ms"] for r in lat], color="k", zorder=3, label="whole decision (torch)"
    )
    axes[0].scatter(
        labels, [r["fast_decision_ms"] for r in lat], color="tab:purple", marker="D", zorder=3,
        label="FastAmat (numba)",
    )  # fmt: skip
    axes[0].scatter(
        labels, [r["fast_random_maps_ms"] for r in lat], color="tab:purple", marker="x", zorder=3,
        label="FastAmat, random dense maps",
    )  # fmt: skip
    axes[0].axhline(1.5, color="r", ls="--", lw=1, label="1.5 ms target (N=6)")
    axes[0].set_ylabel("ms (1 thread)")
    axes[0].set_title("Batch-1 decision latency")
    axes[0].legend(fontsize=8)
    tr = results["training"]
    procs = [r.get("processes", 1) for r in tr]
    labels = [
        f"{r['precision']}\nB={r['worlds']}" + (f" x{p} proc" if p > 1 else "") for r, p in zip(tr, procs)
    ]
    axes[1].bar(labels, [r["agent_samples_per_s"] for r in tr])
    axes[1].axhline(5000, color="r", ls="--", lw=1, label="5,000 target")
    axes[1].set_ylabel("agent-samples / s (2 threads)")
    axes[1].set_title("Training step (fwd + bwd + Adam), Task 2")
    axes[1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=200)
    micro = make_train_config("paper").optim.micro_batch
    ap.add_argument(
        "--train-batch", type=int, nargs="+", default=[256, micro],
        help=f"decision events per training step (x3 robots); default 256 and the recipe's {micro}",
    )  # fmt: skip
    ap.add_argument("--train-steps", type=int, default=10)
    ap.add_argument("--bf16-steps", type=int, default=2, help="bf16 is very slow on CPUs without bf16 units")
    ap.add_argument("--out", default="benchmarks/results/amat.json")
    args = ap.parse_args()
    torch.manual_seed(0)
    model = AMAT().eval()
    batches = [task2_training_batch(events) for events in sorted(set(args.train_batch))]
    results = {
        "machine": {
            "python": platform.python_version(),
            "torch": torch.__version__,
            "cpu_capability": torch.backends.cpu.get_cpu_capability(),
            "native_bf16": native_bf16(),
        },
        "latency": bench_latency(model, args.repeats),
        "acting": bench_acting(model),
        "training": [
            *(bench_training(AMAT().train(), batch, False, args.train_steps) for batch in batches),
            bench_training(AMAT().train(), batches[-1], False, args.train_steps, processes=2),
            bench_training(AMAT().train(), batches[0], True, args.bf16_steps),
        ],
    }
    out = write_json(args.out, results)
    plot(results, out.with_suffix(".png"))
    print(f"wrote {out.with_suffix('.png')}")


if __name__ == "__main__":
    main()
