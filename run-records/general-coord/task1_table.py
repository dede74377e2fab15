"""task1_table.py COMPARE_DIR: the held-out Task-1 table of `amat:general` on the Task 1 page, from `catmip
compare` of its runs with RRT, Nearest, rrt-relay-coord and amat:paper (method names as run: coord0 is the
file shipped as amat_general.pt; paired.csv's rows are method_a − method_b)."""
import csv
import sys

from task_tables import ROWS, bold, cell  # the Task 2/3 tables' rows and cells

ME, COLUMNS, PAPER = "coord0", ["rrt", "nearest", "rrt-relay-coord", "amat_paper"], ["rrt", "nearest", "amat_paper"]
NAMES = {"rrt": "RRT", "nearest": "Nearest", "amat_paper": "`amat_paper`"}
d = sys.argv[1]
succ = {(r["setting"], r["method"]): r for r in csv.DictReader(open(f"{d}/by_setting.csv"))}
diff = {}
for r in csv.DictReader(open(f"{d}/paired.csv")):
    t = tuple(float(r[k]) for k in ("diff", "ci_low", "ci_high"))
    if r["method_a"] == ME:
        diff[(r["setting"], r["method_b"])] = t
    elif r["method_b"] == ME:
        diff[(r["setting"], r["method_a"])] = (-t[0], -t[2], -t[1])
print("| rescued by tick 100 (by the horizon) | `amat:general` | RRT | Nearest | `rrt-relay-coord` | `amat_paper` "
      "| − best of RRT, Nearest and `amat_paper` [95 % CI] | − `rrt-relay-coord` [95 % CI] |")
print("|---|---|---|---|---|---|---|---|")
for comm, noise, label in ROWS:
    s = f"task1-{comm}-noise{noise}-ma10"
    me = succ[(s, ME)]
    vals = [f"{float(me['success_by_100']):.3f} ({float(me['success']):.3f})"]
    vals += [f"{float(succ[(s, m)]['success_by_100']):.3f}" for m in COLUMNS]
    best = min(PAPER, key=lambda m: diff[(s, m)][0])
    vals += [bold(diff[(s, best)], f"{NAMES[best]} {cell(diff[(s, best)])}"),
             bold(diff[(s, "rrt-relay-coord")], cell(diff[(s, "rrt-relay-coord")]))]
    print(f"| {label} | " + " | ".join(vals) + " |")
