"""Property tests of the event engine (hypothesis) and whole-episode determinism."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from catmip_env import make_config
from catmip_env.constants import CLUE, CLUE_BIT, EXPLORED, FREE, OCCUPIED, TARGET, TARGET_BIT
from catmip_env.engines.events import EventEngine, random_valid_actions
from catmip_env.kernels.activation import M_KNEW

from .helpers import bfs_distance


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), size=st.sampled_from([15, 20]), pick=st.integers(0, 10**6))
def test_controller_path_length_equals_bfs_distance(seed, size, pick):
    """On a fully known map a lone explorer reaches any reachable goal in exactly BFS-distance moves."""
    cfg = make_config("task1", map_size=size, team=("explorer",), max_ma_ticks=10_000, horizon_ticks=10_000)
    eng = EventEngine(cfg, 1, seed=seed, goal_mode="cell")
    eng.reset()
    s = eng.state
    g = s.grid[0]
    full = np.full(g.shape, EXPLORED, np.uint8)
    full[(g != FREE) & (g != CLUE)] |= OCCUPIED
    full[g == CLUE] |= CLUE_BIT
    full[g == TARGET] |= TARGET_BIT
    s.belief[0, 0] = full
    eng.mstate[0, 0, M_KNEW] = 1  # knowing the target already: no macro-action end on learning it
    eng.refresh()
    start = tuple(int(x) for x in s.pos[0, 0])
    dist = bfs_distance((g == FREE) | (g == CLUE), start)
    dist[0, :] = dist[-1, :] = dist[:, 0] = dist[:, -1] = -1
    goals = np.argwhere((dist >= 0) & (eng.masks[0, 0].reshape(g.shape) == 1))
    r, c = goals[pick % len(goals)]
    ev = eng.step(np.array([[r * g.shape[1] + c]]))
    assert s.pos[0, 0].tolist() == [r, c]
    assert s.moves[0, 0] == dist[r, c]
    assert ev.event_ticks[0] >= dist[r, c]


@settings(max_examples=15, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    preset=st.sampled_from(["task1", "task2", "train"]),
    comm=st.sampled_from([None, 2.0, 4.0]),
    noise=st.sampled_from([0.0, 0.05]),
    activation=st.sampled_from([(0, 0), (2, 5), (1, 1)]),
    sync=st.booleans(),
    goal_mode=st.sampled_from(["window", "cell"]),
)
def test_event_invariants(seed, preset, comm, noise, activation, sync, goal_mode):
    """Masks are never empty (busy robots: exactly one action); per-event rewards add up to the
    per-tick reward definition; event_ticks add up to the episode length."""
    cfg = make_config(
        preset, comm_sigma=comm, slam_noise=noise, activation=activation, synchronous=sync, horizon_ticks=120
    )
    eng = EventEngine(cfg, 3, seed=seed, goal_mode=goal_mode)
    rng = np.random.default_rng(seed)
    ev = eng.reset()
    total = np.zeros((3, cfg.num_robots))
    ticks = np.zeros(3, np.int64)
    while True:
        live = ~eng.state.done
        counts = eng.masks.sum(-1)
        assert (counts[live] >= 1).all()
        busy = ~eng.active & live[:, None]
        assert (counts[busy] == 1).all()
        if not live.any():
            break
        assert eng.active[live].any(axis=1).all(), "a live world waits at an event nobody decides"
        ev = eng.step(random_valid_actions(eng.masks, rng))
        total[live] += ev.rewards[live]
        ticks[live] += ev.event_ticks[live]
    s = eng.state
    assert np.array_equal(ticks, s.ticks)
    h = cfg.horizon_ticks
    expect = cfg.step_reward * s.moves + cfg.collision_penalty * s.collisions
    found = s.found_tick >= 0
    expect += np.where(found, cfg.find_reward * (1 - 0.9 * s.found_tick / h), 0.0)[:, None]
    rescued = s.rescue_tick >= 0
    expect += np.where(rescued, cfg.rescue_reward * (1 - 0.9 * s.rescue_tick / h), 0.0)[:, None]
    np.testing.assert_allclose(total, expect, atol=1e-9)


def _play(eng, seed, events=400):
    rng = np.random.default_rng(seed)
    out = []
    ev = eng.reset()
    for _ in range(events):
        if eng.state.done.all():
            break
        ev = eng.step(random_valid_actions(eng.masks, rng))
        out.append(
            [x.copy() for x in ev]
            + [eng.obs_global.copy(), eng.obs_local.copy(), eng.masks.copy(), eng.state.pos.copy()]
        )
    return out


def test_full_episode_determinism_with_partial_comm_and_noise():
    cfg = make_config("task2", comm_sigma=2.0, slam_noise=0.05, activation=(2, 5), horizon_ticks=150)
    a = _play(EventEngine(cfg, 4, seed=5), 1)
    b = _play(EventEngine(cfg, 4, seed=5), 1)
    assert len(a) == len(b) > 10
    for x, y in zip(a, b):
        for u, v in zip(x, y):
            assert np.array_equal(u, v)


def test_event_world_does_not_depend_on_its_batch():
    cfg = make_config("task2", comm_sigma=3.0, slam_noise=0.05, activation=(2, 5))
    big = EventEngine(cfg, 3, seed=8)
    solo = EventEngine(cfg, 1, seed=8)
    big.reset(episode_indices=[4, 5, 6])
    solo.reset(episode_indices=[5])
    for _ in range(60):
        # after every step each live world waits at its own next event: world 1 of the batch and the
        # solo world get the same goals, the other worlds choose their first allowed goal
        a_solo = np.argmax(solo.masks, axis=-1)
        a_big = np.argmax(big.masks, axis=-1)
        a_big[1] = a_solo[0]
        ev_s = solo.step(a_solo)
        ev_b = big.step(a_big)
        assert np.array_equal(ev_b.rewards[1], ev_s.rewards[0])
        assert np.array_equal(ev_b.event_ticks[1], ev_s.event_ticks[0])
        assert np.array_equal(big.state.pos[1], solo.state.pos[0])
        assert np.array_equal(big.obs_global[1], solo.obs_global[0])
        if big.state.done[1]:
            break
        if big.state.done.any():
            big.reset(worlds=big.state.done)
