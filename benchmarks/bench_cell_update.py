"""The cell-goal AMAT's training update on a fixed batch: trainable samples per second of one PPO
micro-batch step (``ppo_loss`` forward, backward), one thread, and the loss it computes.

    python benchmarks/bench_cell_update.py [--worlds 2,4] [--events 512] [--repeats 5]
                                           [--out benchmarks/results/cell_update.json]

The batch: one collection of 16 episodes, by a fresh model of the memory model's config (cell goals,
teammate memory; seeded 0), in world ``k`` of the training mixture of ``general-relay-noise`` (2: Task 2,
20x20, 3 robots; 4: Task 3, 32x32, 6 robots), async GAE, its first ``--events`` decision events. Rows:

* ``fp32``: the update as training runs it on a CPU without native bf16 (the reference loss);
* ``bf16``: bfloat16 autocast (``TrainConfig.precision``), timed only where torch reports native bf16
  (AVX-512 BF16 or AMX; elsewhere torch emulates it, several times slower than fp32); its loss minus the
  reference's;
* ``cells-C-L``: the same model with a cheaper per-cell encoder (``AmatConfig.cell_channels`` C,
  ``cell_layers`` L): another model, which would have to be trained again; its speed only.

Profile (fp32, Task 2, AVX2, 2026-12-02): the per-cell encoder's convolutions and their backward are half
of a step, its GELUs and residual adds another quarter.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import torch  # noqa: E402
from common import machine_info, write_json  # noqa: E402

from catmip_rl.amat.pointer import make_model  # noqa: E402
from catmip_rl.training.gae import build_batch  # noqa: E402
from catmip_rl.training.ppo import loss_kwargs, native_bf16, ppo_loss  # noqa: E402
from catmip_rl.training.presets import make_train_config  # noqa: E402
from catmip_rl.training.train import build_run  # noqa: E402

ENCODERS = ((16, 3), (8, 3))  # cheaper per-cell encoders timed beside the model's own (32, 4)


def fixed_batch(world: int, events: int):
    """(config, batch) of world ``world`` of the mixture: see the module docstring."""
    cfg = make_train_config(
        "general-relay-noise", num_worlds=16, eval_every=0, checkpoint_every=0, update_processes=1,
        precision="fp32", seed=0,
    )  # fmt: skip
    run = build_run(cfg)
    collector = run.collector_for(world + 1)  # iteration k plays world k - 1 of the mixture
    rollout = collector.collect(run.model, first_episode=0, generator=run.gen, labeler=run.labeler)
    batch, _ = build_batch(
        rollout, run.value_norm, cfg.loss.gamma, cfg.loss.lam, run.model.config.n_classes, run.device
    )
    return run.model.config, batch.index(torch.arange(min(events, len(batch)))), cfg


def time_step(model, batch, cfg, bf16: bool, repeats: int) -> tuple[float, float]:
    """(median seconds of a forward + backward step with ``cfg``'s loss, its loss)."""
    kwargs = loss_kwargs(cfg.loss, bf16)
    del kwargs["bf16"]

    def step() -> float:
        model.zero_grad(set_to_none=True)
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            loss, _ = ppo_loss(model, batch, **kwargs)
        value = float(loss.detach())
        loss.backward()
        return value

    loss = step()  # warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        step()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), loss


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--worlds", default="2,4", help="worlds of the training mixture (2: Task 2, 4: Task 3)")
    ap.add_argument("--events", type=int, default=512, help="decision events of the batch (the micro-batch)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", default="benchmarks/results/cell_update.json")
    args = ap.parse_args()
    torch.set_num_threads(1)
    rows = []
    for world in (int(w) for w in args.worlds.split(",")):
        config, batch, cfg = fixed_batch(world, args.events)
        samples = int(batch.trainable.sum())
        shape = f"{batch.global_map.shape[-1]}x{batch.global_map.shape[-1]}, {batch.action.shape[1]} robots"
        variants = [("fp32", config, False)]
        variants += [("bf16", config, True)] if native_bf16() else []
        variants += [(f"cells-{c}-{k}", dataclasses.replace(config, cell_channels=c, cell_layers=k), False)
                     for c, k in ENCODERS]  # fmt: skip
        reference = None
        for name, amat, bf16 in variants:
            torch.manual_seed(0)
            model = make_model(amat)
            seconds, loss = time_step(model, batch, cfg, bf16, args.repeats)
            row = {"world": world, "shape": shape, "events": len(batch), "samples": samples, "variant": name,
                   "cell_channels": amat.cell_channels, "cell_layers": amat.cell_layers,
                   "s_per_step": seconds, "samples_per_s": samples / seconds, "loss": loss}  # fmt: skip
            if name == "fp32":
                reference = row
            else:
                row["speed_vs_fp32"] = row["samples_per_s"] / reference["samples_per_s"]
                if name == "bf16":
                    row["loss_minus_fp32"] = loss - reference["loss"]
            rows.append(row)
            print(f"world {world} ({shape}) {name}: {seconds * 1e3:.0f} ms/step, "
                  f"{row['samples_per_s']:.0f} samples/s, loss {loss:.6f}", flush=True)  # fmt: skip
        if not native_bf16():
            print(f"world {world}: bf16 not timed (torch emulates it on this CPU)")
    write_json(args.out, {"machine": machine_info(threads=1), "native_bf16": native_bf16(), "rows": rows})


if __name__ == "__main__":
    main()
