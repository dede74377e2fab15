"""Seconds per training iteration of the paper recipe, split into collection / advantages / update.

    python benchmarks/bench_train.py [--iterations 2] [--epochs 10 2] [--worlds 64] [--bf16]
                                     [--update-processes 2 1] [--device cpu]
                                     [--out benchmarks/results/train.json]

One iteration = 64 ``train``-preset episodes (20x20, 3 robots, horizon 200, activation (2, 5)) collected
by the async-aware collector, asynchronous GAE, and ``--epochs`` full-batch PPO epochs, on ``--threads``
torch threads (2 = the whole machine), the update's gradients computed by ``--update-processes``
processes (2 = the recipe on CPU: two single-threaded processes; 1 = one process on ``--threads``).
Reports env-steps/s end to end (decision events of all worlds per second of iteration, and world-ticks
per second) for the 10-epoch recipe and a 2-epoch one, in fp32 and, with ``--bf16``, CPU bf16 autocast
for the update (the PPO loss's forward pass, in one process; collection in fp32). ``--device cuda``
times the update on the GPU (one process; collection stays on the CPU's ``--threads``).
"""

from __future__ import annotations

import argparse
import platform
import shutil
import tempfile
import time
from pathlib import Path

import torch
from common import write_json

from catmip_rl.training.ppo import native_bf16
from catmip_rl.training.presets import make_train_config
from catmip_rl.training.train import build_run, ppo_iteration


def run(
    epochs: int, iterations: int, threads: int, worlds: int = 64, bf16: bool = False, processes: int = 2,
    device: str = "cpu",
) -> dict:  # fmt: skip
    # autocast runs in the training process only; the gradient processes are CPU ones
    processes = 1 if bf16 or device != "cpu" else processes
    cfg = make_train_config("paper", iterations=iterations, epochs=epochs, threads=threads, num_worlds=worlds,
                            eval_every=0, checkpoint_every=0, update_processes=processes,
                            precision="bf16" if bf16 else "fp32", device=device)  # fmt: skip
    tmp = Path(tempfile.mkdtemp(prefix="catmip_bench_"))
    run = build_run(cfg)
    try:
        for _ in range(iterations):  # the stages of training's loop: collect, GAE + batch, update
            t0 = time.perf_counter()
            row, _, rollout = ppo_iteration(run, tmp)
            iteration_s = time.perf_counter() - t0
    finally:
        run.close()
        shutil.rmtree(tmp, ignore_errors=True)
    # the last iteration is reported: the first includes numba/torch warm-up
    events = rollout.num_samples
    world_ticks = rollout.stats["mean_episode_ticks"] * rollout.valid.shape[1]
    out = {
        "device": device,
        "epochs": epochs,
        "threads": threads,
        "update_processes": processes,
        "num_worlds": worlds,
        "iterations": iterations,
        "precision": "bf16-autocast" if bf16 else "fp32",
        "collect_s": row["time/collect_s"],
        "advantage_s": row["time/advantage_s"],
        "update_s": row["time/update_s"],
        "iteration_s": iteration_s,
        "trainable_samples": row["samples"],  # trainable (robot, event) samples
        "decision_events": events,
        "world_ticks": world_ticks,
        "events_per_s": events / iteration_s,
        "world_ticks_per_s": world_ticks / iteration_s,
    }
    print(
        f"{device}, {epochs:2d} epochs {out['precision']}, {processes} update proc.: "
        f"{iteration_s:.1f} s/iteration "
        f"(collect {out['collect_s']:.1f}, adv. {out['advantage_s']:.2f}, update {out['update_s']:.1f}) "
        f"{out['events_per_s']:,.0f} decision events/s, {out['world_ticks_per_s']:,.0f} world-ticks/s",
        flush=True,
    )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--iterations", type=int, default=2, help="the last one is reported")
    ap.add_argument("--epochs", type=int, nargs="+", default=[10, 2], help="PPO epoch counts to time")
    ap.add_argument("--worlds", type=int, default=64, help="episodes per iteration (64 = the paper)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--bf16", action="store_true", help="also time each recipe with bf16 autocast")
    ap.add_argument(
        "--update-processes",
        type=int,
        nargs="+",
        default=[2],
        help="gradient processes of the update to time",
    )
    ap.add_argument("--device", default="cpu", help="where the update runs: cpu, cuda or cuda:N")
    ap.add_argument("--out", default="benchmarks/results/train.json")
    args = ap.parse_args()
    runs = []
    for bf16 in (False, True) if args.bf16 else (False,):
        for processes in args.update_processes if not bf16 else (1,):
            for epochs in args.epochs:
                runs.append(
                    run(epochs, args.iterations, args.threads, args.worlds, bf16, processes, args.device)
                )
    results = {
        "machine": {
            "python": platform.python_version(),
            "torch": torch.__version__,
            "cpu_capability": torch.backends.cpu.get_cpu_capability(),
            "native_bf16": native_bf16(),
            "gpu": torch.cuda.get_device_name() if args.device != "cpu" else None,
        },  # fmt: skip
        "runs": runs,
    }
    write_json(args.out, results)


if __name__ == "__main__":
    main()
