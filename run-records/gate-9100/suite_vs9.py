"""suite_vs9.py METHOD...: each method's entry against the best paper planner, RRT, rrt-relay-heading,
rrt-relay-coord and amat-general on the suite, setting by setting (from catmip leaderboard --vs)."""
import csv
import glob
import sys

REFS = ["rrt", "nearest", "apf", "utility", "amat_paper", "rrt-relay-heading", "rrt-relay-coord", "amat-general"]
PAPER = ["rrt", "nearest", "apf", "utility", "amat_paper"]
BAR = {"sigma2-noise0": 0.03, "sigma2-noise0.05": 0.03}
fmt = lambda t: "%+.3f [%+.3f, %+.3f]" % t
for method in sys.argv[1:]:
    d = {}
    for m in REFS:
        for f in glob.glob(f"/tmp/lbout/{m}/vs_*.csv"):
            for r in csv.DictReader(open(f)):
                if r["method"] == method:
                    d[(m, r["setting"])] = (float(r["diff_success_by_100"]), float(r["ci_low"]), float(r["ci_high"]))
    settings = sorted({s for _, s in d}, key=lambda s: (s[:5], ["full", "sigma4", "sigma2"].index(s.split("-")[1]), s))
    print(f"\n{method}\n| setting | − best paper planner (which) | bar | − RRT | − rrt-relay-heading | − rrt-relay-coord | − amat:general |")
    print("|---|---|---|---|---|---|---|")
    for s in settings:
        best = min(PAPER, key=lambda m: d.get((m, s), (9,))[0])
        bar = next((b for k, b in BAR.items() if k in s and "task1" not in s), -0.02)
        ok = "✓" if d[(best, s)][0] >= bar else "✗"
        cells = [fmt(d[(m, s)]) if (m, s) in d else "–" for m in ("rrt", "rrt-relay-heading", "rrt-relay-coord", "amat-general")]
        print(f"| {s} | {fmt(d[(best, s)])} ({best}) | {bar:+.2f} {ok} | " + " | ".join(cells) + " |")
