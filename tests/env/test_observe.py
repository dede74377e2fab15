"""Macro-observation channels (docs/design.md#observations) are crops and stamps of the robot's own belief."""

import numpy as np

from catmip_env.constants import (
    CLUE_BIT,
    EXPLORED,
    OBS_CLUE,
    OBS_ONE,
    OCCUPIED,
    STAY,
    TARGET_BIT,
)

from .helpers import preset_engine, random_actions


def _check_world(eng, b):
    st, c = eng.state, eng.cfg.num_classes
    half = eng.cfg.local_size // 2
    h, w = eng.shape
    for i in range(eng.num_robots):
        g, loc = eng.obs_global[b, i], eng.obs_local[b, i]
        bel = st.belief[b, i]
        assert g.shape == (5 + c, h, w) and loc.shape == (4 + c, 2 * half + 1, 2 * half + 1)
        assert set(np.unique(g)) <= {0, OBS_CLUE, OBS_ONE}
        assert np.array_equal(g[0] == OBS_ONE, (bel & EXPLORED) != 0)
        if not eng.noisy:
            assert np.array_equal(g[1] == OBS_ONE, (bel & OCCUPIED) != 0)
        tr, tc = st.target[b]
        if bel[tr, tc] & TARGET_BIT:
            assert (g[2, max(tr - 1, 0) : tr + 2, max(tc - 1, 0) : tc + 2] == OBS_ONE).all()
        else:
            assert np.array_equal(g[2] == OBS_CLUE, (bel & CLUE_BIT) != 0)
        r, cc = st.pos[b, i]
        own = g[4 + c]
        assert own.sum() == OBS_ONE * ((min(r + 2, h) - max(r - 1, 0)) * (min(cc + 2, w) - max(cc - 1, 0)))
        assert own[r, cc] == OBS_ONE
        # other robots in the global map: 3x3 blocks of exactly the neighbourhood members
        expect_g = np.zeros_like(g[4 : 4 + c])
        for j in range(eng.num_robots):
            if j != i and st.comp[b, j] == st.comp[b, i]:
                rj, cj = st.pos[b, j]
                expect_g[st.cls[b, j], max(rj - 1, 0) : rj + 2, max(cj - 1, 0) : cj + 2] = OBS_ONE
        assert np.array_equal(g[4 : 4 + c], expect_g)
        # local map: crop of the belief around the robot, outside = explored + occupied
        for lr in range(2 * half + 1):
            for lc in range(2 * half + 1):
                rr, c2 = r - half + lr, cc - half + lc
                if 0 <= rr < h and 0 <= c2 < w:
                    assert loc[0, lr, lc] == g[0, rr, c2] and loc[1, lr, lc] == g[1, rr, c2]
                    v = bel[rr, c2]
                    want = OBS_ONE if v & TARGET_BIT else OBS_CLUE if v & CLUE_BIT else 0
                    assert loc[2, lr, lc] == want
                else:
                    assert loc[0, lr, lc] == OBS_ONE and loc[1, lr, lc] == OBS_ONE
                    assert not loc[2:, lr, lc].any()
        # other robots in the local map: exactly the neighbourhood members inside the window
        expect = np.zeros_like(loc[4:])
        for j in range(eng.num_robots):
            if j != i and st.comp[b, j] == st.comp[b, i]:
                lr, lc = st.pos[b, j] - st.pos[b, i] + half
                if 0 <= lr <= 2 * half and 0 <= lc <= 2 * half:
                    expect[st.cls[b, j], lr, lc] = OBS_ONE
        assert np.array_equal(loc[4:], expect)
        assert not g[3].any() and not loc[3].any()  # no goal at the primitive level


def test_observations_match_beliefs_along_rollouts():
    rng = np.random.default_rng(0)
    for preset, kw in (
        ("task1", {}),
        ("task3", {"comm_sigma": 2.0}),
        ("task2", {"slam_noise": 0.05}),
    ):
        eng = preset_engine(preset, num_worlds=3, seed=1, **kw)
        for t in range(80):
            eng.step(random_actions(rng, eng))
            if t % 9 == 0:
                for b in range(3):
                    _check_world(eng, b)
            if eng.state.done.any():
                eng.reset(worlds=eng.state.done)


def test_partial_comm_hides_robots_outside_the_neighbourhood():
    eng = preset_engine("task3", num_worlds=2, seed=4, comm_sigma=0.01)
    eng.step(np.full((2, 6), STAY))
    c = eng.cfg.num_classes
    for b in range(2):
        assert len(set(eng.state.comp[b].tolist())) == 6  # everyone alone
        assert not eng.obs_global[b, :, 4 : 4 + c].any()
        assert not eng.obs_local[b, :, 4 : 4 + c].any()


def test_noisy_occupancy_reaches_the_observation():
    eng = preset_engine("task2", num_worlds=2, seed=2, slam_noise=0.3)
    eng.step(np.full((2, 3), STAY))
    st = eng.state
    assert np.array_equal(eng.obs_global[:, :, 1] == OBS_ONE, st.used_occ != 0)
    clean = (st.belief & OCCUPIED) != 0
    assert (clean != (st.used_occ != 0)).any()
