"""The fresh-map rule measured on the committed entries (docs/verification.md's table): per entry, how
often an honest check refuses it, and per run, how often the rule refuses a run that claims 0.25 more than
it plays in one setting or 0.10 more pooled (:func:`catmip_rl.benchmark.fresh_rule.calibrate`). Writes
``docs/figures/fresh_rule_calibration.json`` and, with ``--update``, the table of docs/verification.md
between its ``<!-- calibration -->`` markers.

    python docs/figures/fresh_rule_calibration.py [--draws 2000] [--update docs/verification.md]
"""

from __future__ import annotations

import argparse
import json
import re
import time
from pathlib import Path

from catmip_env.runtime.machine import machine_info
from catmip_rl.benchmark.entry_check import load_entries
from catmip_rl.benchmark.fresh_rule import FRESH_MAPS, calibrate
from catmip_rl.store.files import atomic_write_text

ROOT = Path(__file__).resolve().parents[2]
OUT = Path(__file__).with_name("fresh_rule_calibration.json")
MARK = re.compile(r"(<!-- calibration -->\n).*?(\n<!-- /calibration -->)", flags=re.DOTALL)


def table(found: dict) -> str:
    """docs/verification.md's table of ``found``."""
    worst = {
        key: max(rates[key] for rates in found["false_refusal"].values())
        for key in ("resampled", "posterior")
    }
    one, pooled = found["power_one_setting_0.25"], found["power_pooled_0.10"]
    entries, draws = len(found["false_refusal"]), found["draws"]
    return "\n".join(
        [
            "| what | measured |",
            "|---|---|",
            f"| an honest entry refused (fresh maps resampled from the run's own test ticks) | at most "
            f"{worst['resampled']:.4f} ({entries} entries, {draws:,} checks each) |",
            f"| an honest entry refused (the claim's own noise too: rates from its posterior) | at most "
            f"{worst['posterior']:.4f} |",
            f"| a run claiming 0.25 more than it plays in one setting, refused | {one['min']:.3f} at the "
            f"lowest ({found['runs']} runs; mean {one['mean']:.3f}) |",
            "| a run claiming 0.10 more than it plays pooled over the settings, refused | "
            f"{pooled['min']:.3f} at the lowest (mean {pooled['mean']:.3f}) |",
        ]
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--draws", type=int, default=2_000)
    ap.add_argument("--entries", type=Path, default=ROOT / "leaderboard" / "entries")
    ap.add_argument("--update", type=Path, default=None, help="docs/verification.md")
    args = ap.parse_args()
    start = time.perf_counter()
    found = calibrate(load_entries(args.entries), m=FRESH_MAPS, draws=args.draws)
    found |= {"seconds": time.perf_counter() - start, "machine": machine_info()}
    atomic_write_text(OUT, json.dumps(found, indent=1) + "\n")
    text = table(found)
    print(text)
    if args.update is not None:
        page = args.update.read_text()
        if MARK.search(page) is None:
            raise SystemExit(f"{args.update} has no <!-- calibration --> markers")
        atomic_write_text(args.update, MARK.sub(lambda m: m[1] + text + m[2], page))


if __name__ == "__main__":
    main()
