"""Seconds per training iteration of the paper recipe, split into collection / advantages / update.

    python benchmarks/bench_train.py [--iterations 2] [--epochs 10] [--out benchmarks/results/train.json]

One iteration = 64 ``train``-preset episodes (20x20, 3 robots, horizon 200, activation (2, 5)) collected
by the async-aware collector, asynchronous GAE, and ``--epochs`` full-batch PPO epochs, on ``--threads``
torch threads (2 = the whole machine). Reports env-steps/s end to end (decision events of all worlds
per second of iteration) for the 10-epoch recipe and a 2-epoch one, in fp32 and, with ``--bf16``, CPU
bf16 autocast for the update.
"""

from __future__ import annotations

import argparse
import csv
import platform
import shutil
import tempfile
from pathlib import Path

import torch
from common import write_json

from catmip_rl.config import make_train_config
from catmip_rl.train import train


def run(epochs: int, iterations: int, threads: int) -> dict:
    cfg = make_train_config("paper", iterations=iterations, epochs=epochs, threads=threads,
                            eval_every=0, checkpoint_every=0)  # fmt: skip
    tmp = Path(tempfile.mkdtemp(prefix="catmip_bench_"))
    try:
        train(cfg, tmp / "run", progress=False)
        rows = list(csv.DictReader((tmp / "run" / "metrics.csv").open()))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    last = rows[-1]  # the first iteration includes numba/torch warm-up
    events = float(last["samples"])  # trainable samples; decision events are reported below
    out = {
        "epochs": epochs,
        "threads": threads,
        "collect_s": float(last["time/collect_s"]),
        "advantage_s": float(last["time/advantage_s"]),
        "update_s": float(last["time/update_s"]),
        "iteration_s": float(last["time/iteration_s"]),
        "trainable_samples": events,
    }
    print(
        f"{epochs:2d} epochs: {out['iteration_s']:.1f} s/iteration (collect {out['collect_s']:.1f}, "
        f"advantages {out['advantage_s']:.2f}, update {out['update_s']:.1f})"
    )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--iterations", type=int, default=2, help="the last one is reported")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default="benchmarks/results/train.json")
    args = ap.parse_args()
    results = {
        "machine": {
            "python": platform.python_version(),
            "torch": torch.__version__,
            "cpu_capability": torch.backends.cpu.get_cpu_capability(),
        },  # fmt: skip
        "runs": [run(10, args.iterations, args.threads), run(2, args.iterations, args.threads)],
    }
    write_json(args.out, results)


if __name__ == "__main__":
    main()
