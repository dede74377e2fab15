"""RRT's cluster kernels against a plain reference: 8-connected labels in raster order of each cluster's
first cell; per cluster the reachable valid cell nearest the mean of those cells, and its score."""

import numpy as np

from catmip_env.planners.rrt import cluster_goals, label8


def _reference(cells, counts, dist, valid):
    h, w = cells.shape
    labels, k = np.zeros((h, w), np.int64), 0
    for r, c in np.argwhere(cells):
        if labels[r, c]:
            continue
        k += 1
        labels[r, c], stack = k, [(r, c)]
        while stack:
            y, x = stack.pop()
            for yy in range(max(y - 1, 0), min(y + 2, h)):
                for xx in range(max(x - 1, 0), min(x + 2, w)):
                    if cells[yy, xx] and not labels[yy, xx]:
                        labels[yy, xx] = k
                        stack.append((yy, xx))
    far = max(int(dist[dist >= 0].max()), 1)
    out = []
    for j in range(1, k + 1):
        m = np.argwhere(labels == j)
        m = m[(dist[m[:, 0], m[:, 1]] >= 0) & valid[m[:, 0], m[:, 1]]]
        if len(m):
            r, c = m[np.argmin(((m - m.mean(axis=0)) ** 2).sum(axis=1))]
            out.append((r, c, counts[r, c] - dist[r, c] / far))
    return labels, k, np.array(out).reshape(-1, 3)


def test_cluster_kernels_match_the_reference():
    rng = np.random.default_rng(0)
    for _ in range(50):
        h, w = rng.integers(5, 33, size=2)
        cells = rng.random((h, w)) < rng.uniform(0.05, 0.5)
        dist = np.where(rng.random((h, w)) < 0.8, rng.integers(0, 60, (h, w)), -1).astype(np.int32)
        dist[0, 0] = 0
        valid = rng.random((h, w)) < 0.9
        counts = rng.random((h, w))
        labels, k, want = _reference(cells, counts, dist, valid)
        got_labels, got_k = label8(cells)
        assert got_k == k and (got_labels == labels).all()
        got = cluster_goals(cells, counts, dist, valid)
        assert got.shape == want.shape and np.array_equal(got, want)
