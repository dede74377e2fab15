"""The batched world: whole-episode determinism, batch independence, resets and input checks."""

import numpy as np
import pytest

from catmip_env import BatchedWorld, make_config
from catmip_env.kernels.state import WorldState

from .helpers import random_actions


def _rollout(eng, ticks, seed):
    rng = np.random.default_rng(seed)
    trace = []
    for _ in range(ticks):
        a = random_actions(rng, eng)
        r = eng.step(a)
        trace.append((r.rewards.copy(), r.terminated.copy(), r.truncated.copy()))
        if eng.state.done.any():
            eng.reset(worlds=eng.state.done)
    return trace


@pytest.mark.parametrize("kw", [{}, {"comm_sigma": 2.0, "slam_noise": 0.05}])
def test_same_seed_same_everything_over_whole_episodes(kw):
    cfg = make_config("task1", horizon_ticks=120, **kw)
    e1, e2 = BatchedWorld(cfg, 6, seed=9), BatchedWorld(cfg, 6, seed=9)
    e1.reset()
    e2.reset()
    t1, t2 = _rollout(e1, 400, 0), _rollout(e2, 400, 0)  # >3 episodes per world
    for (r1, a1, b1), (r2, a2, b2) in zip(t1, t2):
        assert np.array_equal(r1, r2) and np.array_equal(a1, a2) and np.array_equal(b1, b2)
    for name in WorldState.__dataclass_fields__:
        assert np.array_equal(getattr(e1.state, name), getattr(e2.state, name)), name
    assert np.array_equal(e1.obs_global, e2.obs_global)
    assert np.array_equal(e1.obs_local, e2.obs_local)


def test_a_world_does_not_depend_on_its_batch():
    """Episode k of seed s evolves identically alone or inside a batch of other worlds."""
    cfg = make_config("task2", comm_sigma=3.0, slam_noise=0.05)
    big = BatchedWorld(cfg, 5, seed=4)
    big.reset(episode_indices=[10, 11, 12, 13, 14])
    solo = BatchedWorld(cfg, 1, seed=4)
    solo.reset(episode_indices=[12])
    rng = np.random.default_rng(0)
    for _ in range(150):
        a = random_actions(rng, big)
        big.step(a)
        solo.step(a[2:3])
        assert np.array_equal(big.state.belief[2], solo.state.belief[0])
        assert np.array_equal(big.state.pos[2], solo.state.pos[0])
        assert np.array_equal(big.obs_global[2], solo.obs_global[0])


def test_reset_numbering_and_partial_resets():
    eng = BatchedWorld(make_config("task1"), 3, seed=0)
    assert eng.reset().tolist() == [0, 1, 2]
    assert eng.state.episode.tolist() == [0, 1, 2]
    eng.reset(worlds=np.array([False, True, False]))
    assert eng.state.episode.tolist() == [0, 3, 2]
    eng.reset(worlds=[0], episode_indices=[1])
    assert eng.state.episode.tolist() == [1, 3, 2]
    grid_ep1 = eng.state.grid[0].copy()
    eng.reset(seed=0)
    assert np.array_equal(eng.state.grid[1], grid_ep1)


def test_engine_input_errors():
    eng = BatchedWorld(make_config("task1"), 2, seed=0)
    eng.reset()
    with pytest.raises(ValueError, match="shape"):
        eng.step(np.zeros((2, 3), np.int64))
    with pytest.raises(ValueError, match="out of range"):
        eng.step(np.array([[0, 4], [0, 0]]))
    with pytest.raises(ValueError, match="integers"):
        eng.step(np.zeros((2, 2), np.float32))
    with pytest.raises(ValueError, match="world indices"):
        eng.reset(worlds=[5])
    with pytest.raises(ValueError, match="episode indices"):
        eng.reset(worlds=[0, 1], episode_indices=[1])
    # never numpy's OverflowError, nor a silent cast: the first bad index is named
    bad_indices = [[2**70, 1], [0, -1], [0, 2**63], np.array([1.0, 2.0]), [1, None]]
    for bad, shown in zip(bad_indices, [2**70, -1, 2**63, 1.0, None]):
        wanted = rf"episode index must be an int in \[0, 2\*\*62\), got {shown}$"
        with pytest.raises(ValueError, match=wanted):
            eng.reset(episode_indices=bad)
    with pytest.raises(ValueError, match="seed"):
        eng.seed(-3)
    with pytest.raises(ValueError, match="num_worlds"):
        BatchedWorld(make_config("task1"), 0)


def test_read_outs():
    eng = BatchedWorld(make_config("task2"), 2, seed=0)
    eng.reset()
    frac = eng.explored_fraction()
    assert frac.shape == (2,) and (0 < frac).all() and (frac < 0.5).all()
    gt = eng.ground_truth(1)
    assert gt.shape == (6, 20, 20) and gt[1].sum() == 1 and gt[4:].sum() == 3
    assert eng.knows_target().shape == (2, 3)
