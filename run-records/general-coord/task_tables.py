"""task_tables.py VS_DIR: the held-out tables of `amat:general` on the Task 2 and Task 3 pages, from the
leaderboard's entries and its paired differences (`catmip leaderboard --entries leaderboard/entries
--out VS_DIR/M --vs M` for M in rrt, nearest, apf, utility, amat_paper, rrt-relay-coord)."""
import csv
import glob
import json
import sys

PAPER = {"rrt": "RRT", "nearest": "Nearest", "apf": "APF", "utility": "Utility", "amat_paper": "`amat_paper`"}
COLUMNS = ["amat-general", "rrt", "nearest", "rrt-relay-coord", "amat_paper"]
ROWS = [("full", "0", "full communication"), ("sigma4", "0", "σ = 4"), ("sigma2", "0", "σ = 2"),
        ("full", "0.05", "full communication, 5 % SLAM noise"), ("sigma4", "0.05", "σ = 4, 5 % SLAM noise"),
        ("sigma2", "0.05", "σ = 2, 5 % SLAM noise")]
sign = lambda x: f"{x:+.3f}".replace("-", "−")
cell = lambda d: f"{sign(d[0])} [{sign(d[1])}, {sign(d[2])}]"  # a paired difference and its CI
bold = lambda d, s: f"**{s}**" if d[1] > 0 or d[2] < 0 else s  # bold where the CI excludes 0


def main(vs_dir: str) -> None:
    entries = {m: json.load(open(f"leaderboard/entries/{m}.json")) for m in COLUMNS}
    diff = {}
    for f in glob.glob(f"{vs_dir}/*/vs_*.csv"):
        for r in csv.DictReader(open(f)):
            if r["method"] == "amat-general":
                diff[(r["vs"], r["setting"])] = tuple(float(r[k]) for k in ("diff_success_by_100", "ci_low", "ci_high"))
    for task in ("task2", "task3"):
        _table(task, entries, diff)


def _table(task, entries, diff):
    print(f"\n{task}\n| rescued by tick 100 (by the horizon) | `amat:general` | RRT | Nearest | `rrt-relay-coord` "
          "| `amat_paper` | − best paper planner [95 % CI] | − `rrt-relay-coord` [95 % CI] |")
    print("|---|---|---|---|---|---|---|---|")
    for comm, noise, label in ROWS:
        s = f"{task}-{comm}-noise{noise}-ma10"
        ours = entries["amat-general"]["settings"][s]
        vals = [f"{ours['success_by_100']:.3f} ({ours['success_rate']:.3f})"]
        vals += [f"{entries[m]['settings'][s]['success_by_100']:.3f}" for m in COLUMNS[1:]]
        best = min(PAPER, key=lambda m: diff[(m, s)][0])
        vals += [bold(diff[(best, s)], f"{PAPER[best]} {cell(diff[(best, s)])}"),
                 bold(diff[("rrt-relay-coord", s)], cell(diff[("rrt-relay-coord", s)]))]
        print(f"| {label} | " + " | ".join(vals) + " |")


if __name__ == "__main__":
    main(sys.argv[1])
