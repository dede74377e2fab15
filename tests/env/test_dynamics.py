"""World dynamics on hand-drawn maps: movement, speeds, communication, rewards, success.

The rules: docs/design.md#world-rules.
"""

import numpy as np
import pytest

from catmip_env.constants import (
    EXPLORED,
    FORWARD,
    OBSTACLE,
    STAY,
    TARGET,
    TARGET_BIT,
    TURN_LEFT,
    TURN_RIGHT,
    WALL,
)

from .helpers import TWO_ROOMS, layout_engine, preset_engine, random_actions

STAYS = np.full((1, 2), STAY)


def _act(eng, *actions):
    return eng.step(np.array([actions], dtype=np.int64))


@pytest.mark.parametrize("comm", [None, 2.0])
def test_robots_never_in_walls_or_on_each_other(comm):
    rng = np.random.default_rng(1)
    eng = preset_engine("task2", num_worlds=8, seed=1, comm_sigma=comm)
    for _ in range(600):
        eng.step(random_actions(rng, eng))
        st = eng.state
        g = st.grid[np.arange(8)[:, None], st.pos[..., 0], st.pos[..., 1]]
        assert not np.isin(g, (WALL, OBSTACLE, TARGET)).any()
        for b in range(8):
            assert len({tuple(p) for p in st.pos[b].tolist()}) == eng.num_robots
        if st.done.any():
            eng.reset(worlds=st.done)


def test_invariants_on_a_hand_drawn_non_square_map():
    """Random walks of three robots on a 7x13 ASCII map: never in walls, obstacles, the target or
    on each other; explored never shrinks under full communication."""
    layout = TWO_ROOMS.replace("#...o.......#", "#2..o.......#")
    eng = layout_engine(layout, team=("rescuer", "explorer", "explorer"), horizon_ticks=10_000)
    st, rng = eng.state, np.random.default_rng(4)
    prev = st.belief.copy()
    for _ in range(2000):
        eng.step(random_actions(rng, eng))
        cells = st.grid[0, st.pos[0, :, 0], st.pos[0, :, 1]]
        assert not np.isin(cells, (WALL, OBSTACLE, TARGET)).any()
        assert len({tuple(p) for p in st.pos[0].tolist()}) == 3
        assert ((prev & ~st.belief) == 0).all()
        prev = st.belief.copy()
        if st.done[0]:
            break
    assert st.grid.shape == (1, 7, 13)


def test_turning_and_forward():
    eng = layout_engine(TWO_ROOMS, team=("explorer", "explorer"))
    st = eng.state
    assert st.pos[0, 0].tolist() == [1, 1] and st.heading[0, 0] == 0
    _act(eng, TURN_RIGHT, STAY)
    assert st.heading[0, 0] == 1  # east -> south
    _act(eng, FORWARD, STAY)
    assert st.pos[0, 0].tolist() == [2, 1]
    _act(eng, TURN_LEFT, STAY)
    _act(eng, TURN_LEFT, STAY)
    assert st.heading[0, 0] == 3  # north
    r = _act(eng, FORWARD, STAY)
    assert st.pos[0, 0].tolist() == [1, 1] and r.rewards[0, 0] == pytest.approx(-0.05)


def test_forward_into_robot_or_wall_fails():
    eng = layout_engine(TWO_ROOMS, team=("explorer", "explorer"), collision_penalty=-1.0)
    st = eng.state
    r = _act(eng, FORWARD, STAY)  # robot_1 stands east of robot_0
    assert st.pos[0, 0].tolist() == [1, 1] and r.rewards[0, 0] == 0.0
    _act(eng, TURN_LEFT, STAY)  # face north: the outer wall
    r = _act(eng, FORWARD, STAY)
    assert st.pos[0, 0].tolist() == [1, 1] and r.rewards[0, 0] == pytest.approx(-1.0)


def test_robots_move_in_id_order():
    """robot_0 moves into the cell robot_1 vacates on the same tick; the reverse order is blocked."""
    eng = layout_engine(TWO_ROOMS, team=("explorer", "explorer"))
    st = eng.state
    _act(eng, FORWARD, FORWARD)
    assert st.pos[0, 0].tolist() == [1, 1] and st.pos[0, 1].tolist() == [1, 3]
    _act(eng, FORWARD, STAY)
    assert st.pos[0, 0].tolist() == [1, 2]


def test_rescuer_moves_every_second_tick():
    eng = layout_engine(TWO_ROOMS, team=("explorer", "rescuer"))
    st = eng.state
    cols = []
    for _ in range(8):
        _act(eng, STAY, FORWARD)
        cols.append(int(st.pos[0, 1, 1]))
    assert cols == [3, 3, 4, 4, 5, 5, 6, 6]


def test_explored_never_shrinks_under_full_communication():
    rng = np.random.default_rng(2)
    eng = preset_engine("task3", num_worlds=4, seed=2)
    prev = eng.state.belief.copy()
    for _ in range(300):
        eng.step(random_actions(rng, eng))
        cur = eng.state.belief
        live = ~eng.state.done
        assert ((prev[live] & ~cur[live]) == 0).all(), "belief bits were lost"
        # full communication: all robots share one belief
        assert (cur == cur[:, :1]).all()
        prev = cur.copy()
        if eng.state.done.any():
            eng.reset(worlds=eng.state.done)
            prev = eng.state.belief.copy()


def test_partial_communication_merges_inside_neighbourhoods_only():
    rng = np.random.default_rng(3)
    eng = preset_engine("task3", num_worlds=8, seed=3, comm_sigma=2.0)
    seen_split = False
    for _ in range(200):
        eng.step(random_actions(rng, eng))
        st = eng.state
        for b in range(8):
            labels = st.comp[b]
            for i in range(eng.num_robots):
                assert labels[i] <= i and labels[labels[i]] == labels[i]  # label = lowest member
                j = labels[i]
                assert (st.belief[b, i] == st.belief[b, j]).all()
            seen_split |= len(set(labels.tolist())) > 1
        if st.done.any():
            eng.reset(worlds=st.done)
    assert seen_split, "with sigma = 2 the team should split at some point"


def test_link_probability_matches_exp_law():
    """Two robots at distance d link with probability exp(-d^2 / sigma^2)."""
    eng = layout_engine(
        """
        #########
        #0..1...#
        #.....T.#
        #########
        """,
        team=("explorer", "explorer"),
        comm_sigma=3.0,
    )
    links = 0
    n = 4000
    for _ in range(n):
        _act(eng, STAY, STAY)
        links += eng.state.comp[0, 1] == 0
        eng.state.ticks[0] = 0  # keep the episode alive
    assert links / n == pytest.approx(np.exp(-9 / 9), abs=0.03)


FIND_MAP = """
##########
#0.......#
#1.....T.#
#........#
##########
"""


def test_find_reward_when_target_first_seen():
    # robots face north (a wall): nothing of the target in view at reset
    lay = FIND_MAP + "headings: N N\n"
    eng = layout_engine(lay, team=("explorer", "rescuer"))
    h = eng.cfg.horizon_ticks
    assert eng.state.found_tick[0] == -1 and (eng.state.pending_reward == 0).all()
    r = _act(eng, TURN_RIGHT, STAY)  # robot_0 faces east on tick 1: the target is in view
    assert eng.state.found_tick[0] == 1
    expect = 100 * (1 - 0.9 * 1 / h)
    assert r.rewards[0].tolist() == pytest.approx([expect, expect])
    r = _act(eng, STAY, STAY)
    assert r.rewards[0].tolist() == [0.0, 0.0]  # paid once


def test_find_reward_at_reset_is_paid_with_the_first_step():
    eng = layout_engine(FIND_MAP, team=("explorer", "rescuer"))  # facing east: target in view
    assert eng.state.found_tick[0] == 0
    assert eng.state.pending_reward[0].tolist() == [100.0, 100.0]
    r = _act(eng, STAY, STAY)
    assert r.rewards[0].tolist() == [100.0, 100.0]
    assert _act(eng, STAY, STAY).rewards[0].tolist() == [0.0, 0.0]


RESCUE_MAP = """
#########
#0......#
#....T..#
#1......#
#########
"""


def _place(eng, i, r, c, heading):
    eng.state.pos[0, i] = (r, c)
    eng.state.heading[0, i] = heading


def test_success_exactly_when_a_target_aware_rescuer_is_adjacent():
    eng = layout_engine(
        RESCUE_MAP + "headings: W W\n", team=("explorer", "rescuer"), comm_sigma=0.01
    )  # (practically) no communication
    st, h = eng.state, eng.cfg.horizon_ticks
    tr, tc = st.target[0]
    # rescuer adjacent to the target but facing away, not knowing it: no success
    _place(eng, 1, tr, tc + 1, 0)  # east of the target, facing east
    st.belief[0, 1] &= ~np.uint8(TARGET_BIT)
    r = _act(eng, STAY, STAY)
    assert not r.terminated[0] and st.rescue_tick[0] == -1
    # an explorer adjacent that knows the target does not rescue
    _place(eng, 0, tr - 1, tc, 1)  # north of the target, facing south: sees it
    r = _act(eng, STAY, STAY)
    assert st.belief[0, 0, tr, tc] & TARGET_BIT and not r.terminated[0]
    # tick 3 (0-based index 2, the rescuer acts): it turns north, sees the target in its own row
    r = _act(eng, STAY, TURN_LEFT)
    assert st.belief[0, 1, tr, tc] & TARGET_BIT
    assert r.terminated[0] and not r.truncated[0] and st.done[0]
    assert st.rescue_tick[0] == 3
    assert r.rewards[0].tolist() == pytest.approx([300 * (1 - 0.9 * 3 / h)] * 2)


def test_success_via_communicated_knowledge():
    """A rescuer that is told the target's location by a teammate rescues without seeing it."""
    eng = layout_engine(RESCUE_MAP + "headings: W W\n", team=("explorer", "rescuer"))
    st = eng.state
    tr, tc = st.target[0]
    _place(eng, 1, tr, tc + 1, 0)  # rescuer east of the target, facing away
    _place(eng, 0, tr - 1, tc - 2, 0)  # explorer sees the target
    r = _act(eng, STAY, STAY)
    assert r.terminated[0]


def test_truncation_at_horizon_and_frozen_after_done():
    eng = layout_engine(TWO_ROOMS, team=("explorer", "explorer"), horizon_ticks=5)
    for t in range(5):
        r = _act(eng, STAY, STAY)
        assert r.truncated[0] == (t == 4) and not r.terminated[0]
    before = eng.state.copy()
    r = _act(eng, FORWARD, FORWARD)
    assert r.rewards[0].tolist() == [0.0, 0.0] and not r.truncated[0]
    assert (eng.state.pos == before.pos).all() and eng.state.ticks[0] == 5


def test_slam_noise_flips_used_occupancy_only():
    rng = np.random.default_rng(5)
    eng = preset_engine("task2", num_worlds=4, seed=5, slam_noise=0.05)
    flips, cells = 0, 0
    for _ in range(60):
        eng.step(random_actions(rng, eng))
        st = eng.state
        explored = (st.belief & EXPLORED) != 0
        clean = (st.belief & 2) != 0
        used = st.used_occ != 0
        assert not (used & ~explored).any()  # unexplored cells are never flipped
        b, i = np.meshgrid(np.arange(4), np.arange(3), indexing="ij")
        assert not used[b, i, st.pos[..., 0], st.pos[..., 1]].any()  # own cell free
        flips += (used != clean)[explored].sum()
        cells += explored.sum()
    assert flips / cells == pytest.approx(0.05, abs=0.01)
