"""The benchmark's job runner scaled out: maps per second of a planner and of an AMAT entry played by
``map_jobs`` (the path of ``catmip bench suite``) on 1 and 2 local workers and on a private Ray cluster
of 2 workers on loopback, start-up included (a workload long enough that it stays small: say what it
was), Ray's overhead against the local pool at equal workers, and a projection for 16 and 64 workers
from the measured per-chunk time and that overhead. Run it with nothing else running.

    python benchmarks/bench_suite_scale.py [--maps 800] [--out benchmarks/results/suite_scale.json]

Needs the distributed extra (``make test-distributed``) for the Ray rows; without it they are left out
and the output says so. The results go to ``--out`` with the machine (``common.machine_info``).
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from common import machine_info, write_json  # noqa: E402

from catmip_rl.benchmark import jobs as jobs_module  # noqa: E402
from catmip_rl.benchmark.jobs import Job, map_jobs  # noqa: E402
from catmip_rl.evaluation.evaluate import EvalSetting  # noqa: E402
from catmip_rl.evaluation.methods import parse_method  # noqa: E402

METHODS = {"planner": "rrt-relay-coord", "amat": "amat:paper"}
SETTING = EvalSetting("task2", "2", 0.0)
SUITE_CHUNKS = 12 * 1000 // 100  # a full entry of one run: 12 settings x 1,000 maps in chunks of 100


def timed(method: str, maps: int, backend: str, workers: int) -> float:
    """Seconds of one ``map_jobs`` call: ``maps`` maps of the validation split in chunks, start-up
    (pool or Ray cluster) included."""
    with tempfile.TemporaryDirectory() as tmp:
        job = Job(parse_method(method), SETTING, maps, 1000, str(Path(tmp) / "run"), threads=1, sampled=False)
        t0 = time.perf_counter()
        map_jobs([job], workers, False, "", backend=backend)
        return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--maps", type=int, default=800, help="maps of Task 2, sigma 2 per measurement")
    ap.add_argument("--out", default="benchmarks/results/suite_scale.json")
    args = ap.parse_args(argv)
    try:
        import ray  # noqa: F401

        backends = [("local", 1), ("local", 2), ("ray", 2)]
    except ImportError:
        print("Ray is not installed (make test-distributed): the Ray rows are left out")
        backends = [("local", 1), ("local", 2)]
    chunk = jobs_module.CHUNK_MAPS
    startup = {}
    if any(b == "ray" for b, _ in backends):  # what starting and stopping a private cluster costs alone
        import ray

        from catmip_rl.adapters.ray_tasks import ray_init_config

        t0 = time.perf_counter()
        ray.init(**ray_init_config(None, 2), logging_level="ERROR")
        ray.shutdown()
        startup["ray"] = time.perf_counter() - t0
        print(f"a private Ray cluster starts and stops in {startup['ray']:.1f} s")
    rows = []
    for kind, method in METHODS.items():
        timed(method, chunk, "local", 1)  # compile (cached) and load once
        for backend, workers in backends:
            seconds = timed(method, args.maps, backend, workers)
            row = {"method": method, "kind": kind, "backend": backend, "workers": workers, "maps": args.maps,
                   "seconds": seconds, "maps_per_s": args.maps / seconds}  # fmt: skip
            rows.append(row)
            print(f"{kind} {backend} x{workers}: {seconds:.1f} s, {args.maps / seconds:.1f} maps/s")
    out = {"machine": machine_info(), "setting": SETTING.label, "chunk_maps": chunk, "startup_s": startup,
           "rows": rows}  # fmt: skip
    out["scaling"] = [_scaling(rows, kind, chunk, startup) for kind in METHODS]
    for s in out["scaling"]:
        print(s)
    write_json(args.out, out)
    return out


def _scaling(rows: list[dict], kind: str, chunk: int, startup: dict) -> dict:
    """A method's speed-up, Ray's overhead at 2 workers and the projected time of a full entry (12 x
    1,000 maps of this setting's cost) on 16 and 64 workers: ceil(chunks / W) chunk times, each the
    measured time of one chunk on one worker, times (1 + overhead)."""
    got = {(r["backend"], r["workers"]): r for r in rows if r["kind"] == kind}
    one, two = got[("local", 1)], got[("local", 2)]
    per_chunk = one["seconds"] * chunk / one["maps"]
    out = {"kind": kind, "speedup_local_2": one["seconds"] / two["seconds"], "seconds_per_chunk": per_chunk}
    if ("ray", 2) in got:
        overhead = got[("ray", 2)]["seconds"] / two["seconds"] - 1
        out["ray_overhead_2"] = overhead
        out["ray_startup_share"] = startup.get("ray", 0.0) / got[("ray", 2)]["seconds"]
        out["projected_entry_seconds"] = {
            str(w): math.ceil(SUITE_CHUNKS / w) * per_chunk * (1 + max(overhead, 0.0)) for w in (1, 16, 64)
        }
    return out


if __name__ == "__main__":
    main()
