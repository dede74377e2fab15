"""What the rollout teacher costs per episode and per searched decision
against its base planner ``rrt-relay-coord``, at a few budgets (one thread), and with ``--paired`` what it
gains on the same maps (rescued by tick 100, paired bootstrap over maps: ``catmip compare``'s statistics).

    python benchmarks/bench_rollout.py [--maps 8] [--seed 31100] [--budgets news-k4s4h40,...]
                                       [--paired] [--out benchmarks/results/rollout.json]

A budget is ``WHEN-kKsSHH``: when it searches (news, late, both, always), K candidates, S samples,
H ticks simulated. Maps: episodes 0 .. maps-1 of ``--seed`` (never the test split nor seed 1000).
"""

from __future__ import annotations

import argparse
import os
import re
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from common import machine_info, write_json  # noqa: E402

from catmip_env.planners.rollout import RolloutPlanner  # noqa: E402

BUDGETS = ("news-k4s4h40", "both-k4s4h40", "always-k4s8h60")
FORBIDDEN_SEEDS = (1000, 20261201)  # the validation and test splits: not for choices reported as held-out


def parse_budget(text: str) -> dict:
    m = re.fullmatch(r"(news|late|both|always)-k(\d+)s(\d+)h(\d+)", text)
    if m is None:
        raise SystemExit(f"budget {text!r} is not WHEN-kKsSHH (e.g. news-k4s4h40)")
    return {"when": m[1], "candidates": int(m[2]), "samples": int(m[3]), "horizon": int(m[4])}


def score(result) -> tuple[np.ndarray, np.ndarray]:
    """(E,) rescued by tick 100 and (E,) rescue tick (the horizon when not rescued) per map."""
    horizon = len(result.curve) - 1
    ticks = np.array([horizon if e["rescue_tick"] is None else e["rescue_tick"] for e in result.episodes])
    return (ticks <= 100).astype(float), ticks.astype(float)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", default="task2")
    ap.add_argument("--comm", default="2")
    ap.add_argument("--noise", type=float, default=0.05)
    ap.add_argument("--maps", type=int, default=8)
    ap.add_argument("--seed", type=int, default=31100)
    ap.add_argument("--budgets", default=",".join(BUDGETS))
    ap.add_argument("--late-tick", type=int, default=60)
    ap.add_argument("--paired", action="store_true", help="paired differences against the base planner")
    ap.add_argument("--out", default="benchmarks/results/rollout.json")
    args = ap.parse_args()
    if args.seed in FORBIDDEN_SEEDS:
        raise SystemExit(f"seed {args.seed} is a split the benchmark reports on: choose a fresh one")
    from catmip_rl.evaluation.evaluate import EvalSetting, evaluate

    setting = EvalSetting(args.task, args.comm, args.noise)
    evaluate("rrt-relay-coord", setting, 1, args.seed)  # compile the kernels outside the timing
    t0 = time.perf_counter()
    base = evaluate("rrt-relay-coord", setting, args.maps, args.seed)
    base_s = time.perf_counter() - t0
    base_hit, base_tick = score(base)
    rows = [
        {
            "budget": "base (rrt-relay-coord)",
            "s_per_episode": base_s / args.maps,
            "by_100": float(base_hit.mean()),
            "mean_rescue_tick": float(base_tick.mean()),
            "ticks": base_tick.astype(int).tolist(),
        }
    ]
    print(f"base: {base_s / args.maps:.3f} s/episode, by tick 100 {base_hit.mean():.3f}", flush=True)
    for text in args.budgets.split(","):
        knobs = parse_budget(text)
        planner = RolloutPlanner(seed=args.seed, late_tick=args.late_tick, **knobs)
        t0 = time.perf_counter()
        result = evaluate("rollout-coord", setting, args.maps, args.seed, policy=planner)
        wall = time.perf_counter() - t0
        hit, tick = score(result)
        st = planner.stats
        row = {
            "budget": text,
            **knobs,
            "late_tick": args.late_tick,
            "s_per_episode": wall / args.maps,
            "times_base": wall / base_s,
            "searches_per_episode": st["searches"] / args.maps,
            "s_per_search": st["search_s"] / max(st["searches"], 1),
            "changed_share": st["changed"] / max(st["searches"], 1),
            "sim_worlds_per_search": st["sim_worlds"] / max(st["searches"], 1),
            "by_100": float(hit.mean()),
            "mean_rescue_tick": float(tick.mean()),
            "rescuer_search_share": st["rescuer_searches"] / max(st["searches"], 1),
            "rescuer_changed_share": st["rescuer_changed"] / max(st["changed"], 1),
            "ticks": tick.astype(int).tolist(),  # per map: the paired differences can be pooled later
        }
        if args.paired:
            from catmip_rl.evaluation.stats import mcnemar_p, paired_difference

            row["by_100_minus_base"] = paired_difference(hit, base_hit)
            row["rescue_tick_minus_base"] = paired_difference(tick, base_tick)
            row["mcnemar_p"] = mcnemar_p(hit > 0, base_hit > 0)
        rows.append(row)
        d = row.get("by_100_minus_base")
        gain = "" if d is None else f", {d['diff']:+.3f} [{d['ci_low']:+.3f}, {d['ci_high']:+.3f}]"
        cost = f"{row['s_per_episode']:.2f} s/episode ({row['times_base']:.0f}x)"
        search = f"{row['s_per_search'] * 1e3:.0f} ms/search"
        print(f"{text}: {cost}, {search}, by tick 100 {hit.mean():.3f}{gain}", flush=True)
    results = {
        "machine": machine_info(threads=1),
        "setting": setting.label,
        "seed": args.seed,
        "maps": args.maps,
        "rows": rows,
    }
    write_json(args.out, results)


if __name__ == "__main__":
    main()
