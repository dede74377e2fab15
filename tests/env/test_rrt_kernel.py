"""The RRT planner's tree kernel against a plain numpy statement of its rule."""

import numpy as np
import pytest

from catmip_env.planners.rrt import grow_rrt


def _reference_rrt(explored, occupied, r0, c0, u, step, max_targets):
    """The rule the kernel implements, by brute force: each sample extends the node nearest to it by at
    most ``step``, except that a node of the sample's own cell within one cell of it is taken as it is."""
    h, w = explored.shape
    nodes = [(r0, c0)]
    targets = []
    for ur, uc in u:
        sr, sc = ur * h - 0.5, uc * w - 0.5
        pts = np.array(nodes)
        d2 = (pts[:, 0] - sr) ** 2 + (pts[:, 1] - sc) ** 2
        cells = np.floor(pts + 0.5)
        near_own = (cells[:, 0] == np.floor(sr + 0.5)) & (cells[:, 1] == np.floor(sc + 0.5)) & (d2 <= 1.0)
        if near_own.any():
            best = int(np.flatnonzero(near_own)[np.argmin(d2[near_own])])
        else:
            best = int(np.argmin(d2))
        dist = np.sqrt(d2[best])
        if dist < 1e-9:
            continue
        f = min(step / dist, 1.0)
        nr = pts[best, 0] + (sr - pts[best, 0]) * f
        nc = pts[best, 1] + (sc - pts[best, 1]) * f
        gr, gc = int(nr + 0.5), int(nc + 0.5)
        if gr < 1 or gc < 1 or gr > h - 2 or gc > w - 2 or occupied[gr, gc]:
            continue
        if not explored[gr, gc]:
            targets.append((gr, gc))
            if len(targets) >= max_targets:
                break
            continue
        nodes.append((nr, nc))
    return targets


@pytest.mark.parametrize("seed", range(6))
def test_the_kernel_grows_the_reference_tree(seed):
    rng = np.random.default_rng(seed)
    h, w = rng.integers(12, 33, size=2)
    occupied = rng.random((h, w)) < 0.2
    occupied[0, :] = occupied[-1, :] = occupied[:, 0] = occupied[:, -1] = True
    explored = rng.random((h, w)) < rng.uniform(0.4, 0.95)
    free = np.argwhere(explored & ~occupied)
    r0, c0 = (float(x) for x in free[rng.integers(len(free))])
    u = rng.random((4000, 2))
    out = np.empty((500, 2), np.int64)
    n = grow_rrt(explored, occupied, r0, c0, u, 0.5, 500, out)
    assert [tuple(t) for t in out[:n].tolist()] == _reference_rrt(explored, occupied, r0, c0, u, 0.5, 500)
    assert n > 0
