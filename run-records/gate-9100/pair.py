"""pair.py TAG A B [A B ...]: paired success-by-100 differences A - B (normal 95 % CI) on gate3's TAG runs."""
import csv, sys
import numpy as np

def load(name, tag):
    out = {}
    for r in csv.DictReader(open(f"/root/runs/gate3/{name}/{tag}/episodes.csv")):
        t = r["rescue_tick"]
        out[(r["episode"], r["map_hash"])] = r["rescued"] == "True" and t != "" and int(t) <= 100
    return out

tag, pairs = sys.argv[1], sys.argv[2:]
for a, b in zip(pairs[::2], pairs[1::2]):
    A, B = load(a, tag), load(b, tag)
    keys = sorted(set(A) & set(B))
    x = np.array([A[k] - B[k] for k in keys], float)
    m, se = x.mean(), x.std(ddof=1) / np.sqrt(len(x))
    print(f"{tag} {a} {np.mean([A[k] for k in keys]):.4f} - {b} {np.mean([B[k] for k in keys]):.4f} = "
          f"{m:+.4f} [{m - 1.96 * se:+.3f}, {m + 1.96 * se:+.3f}] ({len(keys)} maps)")
