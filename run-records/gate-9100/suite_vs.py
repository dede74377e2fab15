"""The hint entry against every planner, the teacher and amat-general on the suite: a table per setting."""
import csv
import glob

REFS = ["rrt", "nearest", "apf", "utility", "rrt-relay-heading", "amat-general", "amat_paper"]
PLANNERS = ["rrt", "nearest", "apf", "utility"]
d = {}
for m in REFS:
    for f in glob.glob(f"/tmp/lbout/{m}/vs_*.csv"):
        for r in csv.DictReader(open(f)):
            if r["method"] == "amat-general-hint":
                d[(m, r["setting"])] = (float(r["diff_success_by_100"]), float(r["ci_low"]), float(r["ci_high"]))
settings = sorted({s for _, s in d}, key=lambda s: (s[:5], ["full", "sigma4", "sigma2"].index(s.split("-")[1]), s))
fmt = lambda t: "%+.3f [%+.3f, %+.3f]" % t
print("| setting | − best paper planner (which) | − RRT | − teacher | − amat:general |")
print("|---|---|---|---|---|")
for s in settings:
    best = min(PLANNERS + ["amat_paper"], key=lambda m: d.get((m, s), (9,))[0])
    print(f"| {s} | {fmt(d[(best, s)])} ({best}) | {fmt(d[('rrt', s)])} | {fmt(d[('rrt-relay-heading', s)])} | {fmt(d[('amat-general', s)])} |")
