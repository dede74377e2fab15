"""Copy a run of ``examples/mappo_torchrl.py`` into this folder and print its README row.

    python run-records/marl-pool4/record.py /root/runs/marl/mappo-pool4-task2-s1 mappo-task2-s1
    python run-records/marl-pool4/record.py --snapshot /root/runs/marl/mappo-pool4-task3-s0 mappo-task3-s0

A finished run gives its config, metrics (``metrics.csv.gz``) and policy files (weights only; ``policy.py`` pointing here),
and the row: training success over the last 200 iterations and the 200 before, and by tick 100 on the
task's 100 protocol maps beside Nearest, ``random-rescue`` and ``random-uniform`` (its ``eval/``, with
``random-rescue`` played here). ``--snapshot`` is for a run that goes on in a later sitting: config,
metrics and ``weights.pt`` (half precision), what ``--resume --from-weights`` needs if its ``state.pt``
is lost.
"""

from __future__ import annotations

import argparse
import csv
import gzip
import json
import shutil
from pathlib import Path

import numpy as np

HERE = Path(__file__).parent
FINISHED = ("config.json", "metrics.csv", "policy.pt", "policy.json")
SNAPSHOT = ("config.json", "metrics.csv", "weights.pt")


def training_success(run: Path) -> tuple[int, float, float, float]:
    """Iterations, minutes, and the mean training success of the last 200 iterations and the 200 before."""
    with (run / "metrics.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    rate = np.array([float(r["success_rate"]) for r in rows])  # nan: no episode ended in the batch
    last, before = rate[-200:], rate[-400:-200]
    return len(rows), float(rows[-1]["minutes"]), _mean(last), _mean(before)


def _mean(rates: np.ndarray) -> float:
    return float(np.nanmean(rates)) if np.isfinite(rates).any() else float("nan")


def protocol_row(run: Path, task: str) -> dict[str, float]:
    """By tick 100 on the protocol's maps: the run's own evaluation (``eval/``) and ``random-rescue``."""
    from catmip_rl.evaluation.evaluate import EvalSetting, evaluate

    summaries = sorted(run.glob("eval/*/summary.json"))
    if not summaries:
        raise SystemExit(f"{run}/eval/ holds no evaluation: the run has not finished")
    rates = {p.parent.name: json.loads(p.read_text())["success_by_100"] for p in summaries}
    episodes = json.loads(summaries[0].read_text())["episodes"]
    rates["random-rescue"] = evaluate("random-rescue", EvalSetting(task), episodes=episodes).summary[
        "success_by_100"
    ]
    return rates


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path, help="the run's --out folder")
    ap.add_argument("name", help="the record's folder here, e.g. mappo-task2-s1")
    ap.add_argument("--snapshot", action="store_true", help="an unfinished run: weights.pt, no policy files")
    args = ap.parse_args(argv)
    files = SNAPSHOT if args.snapshot else FINISHED
    missing = [f for f in files if not (args.run / f).is_file()]
    if missing:
        raise SystemExit(f"{args.run} lacks {missing}")
    dest = HERE / args.name
    dest.mkdir(exist_ok=True)
    for f in files:
        if f == "metrics.csv":  # the per-iteration log, compressed (a third of the bytes): zcat reads it
            with (args.run / f).open("rb") as src, gzip.open(dest / f"{f}.gz", "wb", mtime=0) as out:
                shutil.copyfileobj(src, out)
        else:
            shutil.copy2(args.run / f, dest / f)
    iterations, minutes, last, before = training_success(args.run)
    row = f"| `{args.name}` | {iterations:,} | {minutes:.1f} | {last:.3f} / {before:.3f} |"
    if args.snapshot:
        print(f"snapshot of iteration {iterations} in {dest}\n{row} (in progress) |")
        return
    from catmip_rl.adapters.torchrl_marl import POLICY_PY

    (dest / "policy.py").write_text(POLICY_PY.replace("{folder}", str(dest.relative_to(HERE.parent.parent))))
    config = json.loads((args.run / "config.json").read_text())
    rates = protocol_row(args.run, config["task"])
    print(row, ", ".join(f"{k} {v:.2f}" for k, v in rates.items()), "|")


if __name__ == "__main__":
    main()
