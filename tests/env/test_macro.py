"""Macro-action layer on hand-built scenarios: ends, activation rules, speeds, masks.

The rules: docs/design.md#macro-actions-and-activation.
"""

import numpy as np
import pytest

from catmip_env import EnvConfig
from catmip_env.constants import WALL
from catmip_env.engines.events import EventEngine, random_valid_actions
from catmip_env.kernels.activation import M_DEADLINE, M_STANDBY

OPEN = """
############
#0.........#
#..........#
#1.........#
######.#####
#T.........#
############
"""


def engine(layout=OPEN, team=("explorer", "explorer"), seed=0, goal_mode="window", **kw):
    kw.setdefault("activation", (0, 0))
    cfg = EnvConfig(layout=layout, team=team, horizon_ticks=kw.pop("horizon_ticks", 200)).replace(**kw)
    eng = EventEngine(cfg, 1, seed=seed, goal_mode=goal_mode)
    eng.reset()
    return eng


def window(dr, dc, d=7):
    """Window action of offset (dr, dc)."""
    return (dr + d // 2) * d + (dc + d // 2)


def step(eng, *actions):
    ev = eng.step(np.array([actions], np.int64))
    return ev


def test_reset_is_a_joint_decision():
    eng = engine()
    assert eng.active.all() and eng.state.ticks[0] == 0


def test_goal_reached_ends_the_macro_action():
    eng = engine()
    ev = step(eng, window(0, 3), window(0, 3))
    assert ev.event_ticks[0] == 3 and ev.active[0].all()
    assert eng.state.pos[0].tolist() == [[1, 4], [3, 4]]


def test_unreachable_goal_ends_at_once():
    walled = """
    #########
    #0..#...#
    #...#...#
    #...#...#
    #1..#...#
    #...#####
    #.T.#####
    #########
    """
    eng = engine(walled, goal_mode="cell")
    w = eng.shape[1]
    known = eng.state.belief[0, 0]
    assert (known[1:5, 4] & 2).all() and not known[1, 5] & 1  # wall seen, (1, 5) unexplored
    assert eng.masks[0, 0, 1 * w + 5] == 1  # unexplored goals are allowed
    ev = step(eng, 1 * w + 5, 4 * w + 3)  # robot_0's goal lies behind the known wall
    assert ev.event_ticks[0] == 1 and ev.active[0].tolist() == [True, False]
    assert eng.state.pos[0, 0].tolist() == [1, 1]


def test_goal_taken_by_a_robot_ends_the_macro_action():
    eng = engine(goal_mode="cell")
    w = eng.shape[1]
    goal = 2 * w + 3
    step(eng, goal, goal)  # both head for (2, 3); robot_0 (first in id order) gets there first
    st = eng.state
    while not eng.active[0, 1]:
        step(eng, 2 * w + 3 if st.pos[0, 0].tolist() == [2, 3] else 0, 0)
    assert st.pos[0, 0].tolist() == [2, 3] and st.pos[0, 1].tolist() != [2, 3]
    assert st.ticks[0] < 10  # ended by the occupied goal, not by max_ma_ticks


def test_learning_the_target_ends_the_macro_action():
    eng = engine(
        OPEN.replace("#T.........#", "#..........#").replace("#1.........#", "#1.......T.#") + "headings: N N"
    )
    assert eng.state.found_tick[0] == -1
    ev = step(eng, window(0, 3), window(0, 3))
    assert eng.state.found_tick[0] == ev.event_ticks[0] == 3
    assert eng.state.pos[0, 0].tolist() == [1, 3]  # not on its goal (1, 4): ended by (c)
    assert ev.active[0].all()
    assert ev.rewards[0, 0] == pytest.approx(100 * (1 - 0.9 * 3 / 200) - 0.1)


def test_max_ma_ticks_ends_the_macro_action():
    eng = engine(max_ma_ticks=2)
    ev = step(eng, window(0, 3), window(0, 3))
    assert ev.event_ticks[0] == 2 and ev.active[0].all()
    assert eng.state.pos[0].tolist() == [[1, 3], [3, 3]]


def test_rescuer_moves_every_second_tick_at_the_macro_level():
    eng = engine(team=("rescuer", "explorer"))
    ev = step(eng, window(0, 2), window(0, 3))
    assert ev.event_ticks[0] == 3 and ev.active[0].tolist() == [True, True]
    assert eng.state.pos[0].tolist() == [[1, 3], [3, 4]]


def test_asynchronous_delay_and_coactivation():
    """robot_0 ends at tick 1, robot_1 at tick 3, activation (2, 5): robot_0 activates alone at
    1 + d0 if that comes before tick 5; otherwise both are ready at tick 5 and co-activate."""
    seen = set()
    for seed in range(40):
        eng = engine(seed=seed, activation=(2, 5))
        ev = step(eng, window(0, 1), window(0, 3))
        d0 = int(eng.mstate[0, 0, M_DEADLINE])
        assert 2 <= d0 <= 5
        if d0 <= 3:
            assert ev.event_ticks[0] == 1 + d0 and ev.active[0].tolist() == [True, False]
            seen.add("alone")
        else:
            assert ev.event_ticks[0] == 5 and ev.active[0].tolist() == [True, True]
            seen.add("together")
    assert seen == {"alone", "together"}


def test_coactivation_only_inside_a_neighbourhood():
    far = """
    ####################
    #0.................#
    #..................#
    #.................1#
    #........T.........#
    ####################
    headings: E W
    """
    # full communication: both end at tick 1, both ready at w = t_min = 2 -> together at tick 3
    eng = engine(far, activation=(2, 5))
    ev = step(eng, window(0, 1), window(0, -1))
    assert ev.event_ticks[0] == 3 and ev.active[0].all()
    # no links: each activates alone at its own deadline
    for seed in range(10):
        eng = engine(far, seed=seed, activation=(2, 5), comm_sigma=0.01)
        ev = step(eng, window(0, 1), window(0, -1))
        d = eng.mstate[0, :, M_DEADLINE]
        assert ev.event_ticks[0] == 1 + d.min()
        assert ev.active[0].tolist() == (d == d.min()).tolist()


def test_evaluation_activation_decides_at_once():
    eng = engine(activation=(0, 0))
    ev = step(eng, window(0, 1), window(0, 3))
    assert ev.event_ticks[0] == 1 and ev.active[0].tolist() == [True, False]
    ev = step(eng, window(0, 0), 0)  # robot_0 stays; robot_1's entry is ignored (busy)
    assert ev.event_ticks[0] == 1 and ev.active[0].tolist() == [True, False]
    ev = step(eng, window(0, 0), 0)
    assert ev.event_ticks[0] == 1 and ev.active[0].all()  # robot_1 reached (3, 4) at tick 3


def test_synchronous_mode():
    eng = engine(synchronous=True, max_ma_ticks=4)
    ev = step(eng, window(0, 1), window(0, 3))
    assert ev.event_ticks[0] == 4 and ev.active[0].all()
    assert eng.mstate[0, 0, M_STANDBY]  # robot_0 finished early and waited
    ev = step(eng, window(0, 1), window(0, 1))
    assert ev.event_ticks[0] == 4 and eng.state.ticks[0] == 8


def _reference_mask(bel, pos, i, d=7):
    """The masking rule of docs/design.md#goals-and-masks written out in plain Python."""
    h, w = bel.shape
    occ = (bel & 2) != 0
    out = np.zeros(d * d, np.int8)
    r0, c0 = pos[i]
    for a in range(d * d):
        r, c = r0 + a // d - d // 2, c0 + a % d - d // 2
        if not (1 <= r <= h - 2 and 1 <= c <= w - 2) or occ[r, c]:
            continue
        if any((r, c) == tuple(p) for j, p in enumerate(pos) if j != i):
            continue
        if occ[r - 1, c] and occ[r + 1, c] and occ[r, c - 1] and occ[r, c + 1]:
            continue
        out[a] = 1
    out[(d * d) // 2] = 1
    return out


def test_masks_follow_the_rule():
    eng = engine()
    st = eng.state
    # hand-edit robot_0's belief: a pocket at (2, 3) whose four neighbours are known obstacles
    for r, c in ((1, 3), (3, 3), (2, 2), (2, 4)):
        st.belief[0, :, r, c] = 1 | 2
    st.belief[0, :, 2, 3] = 0
    st.belief[0, :, 1, 2] = 1  # explored free
    st.belief[0, :, 3, 4] = 0  # unexplored
    eng.refresh()
    m = eng.masks[0, 0]
    assert np.array_equal(m, _reference_mask(st.belief[0, 0], st.pos[0], 0))
    assert m[window(1, 2)] == 0  # the pocket
    assert m[window(0, 2)] == 0  # a known obstacle
    assert m[window(2, 0)] == 0  # robot_1's cell
    assert m[window(-1, 0)] == 0  # the outer wall
    assert m[window(2, 3)] == 1  # unexplored: allowed
    assert m[window(0, 0)] == 1
    # along random rollouts every active robot's mask equals the reference, busy ones keep
    rng = np.random.default_rng(0)
    eng = engine()
    for _ in range(40):
        for i in range(2):
            if eng.active[0, i]:
                assert np.array_equal(
                    eng.masks[0, i], _reference_mask(eng.state.belief[0, i], eng.state.pos[0], i)
                )
            else:
                assert eng.masks[0, i].sum() == 1 and eng.masks[0, i, 24] == 1
        a = random_valid_actions(eng.masks, rng)
        eng.step(a)
        if eng.state.done[0]:
            break


def test_cell_mode():
    eng = engine(goal_mode="cell")
    h, w = eng.shape
    assert eng.num_actions == h * w
    m = eng.masks[0, 0]
    assert m[0] == 0 and m[1 * w + 1] == 1  # a wall; own cell
    ev = step(eng, 1 * w + 5, 3 * w + 2)
    assert ev.active[0, 1] and eng.state.pos[0, 1].tolist() == [3, 2]
    busy = np.flatnonzero(~eng.active[0])
    for i in busy:
        g = eng.state.goal[0, i]
        assert eng.masks[0, i].sum() == 1 and eng.masks[0, i, g[0] * w + g[1]] == 1


def test_invalid_actions_raise_or_become_stay():
    eng = engine()
    with pytest.raises(ValueError, match="robot_0 .* out of range"):
        step(eng, 49, 0)
    with pytest.raises(ValueError, match="robot_1 .* masked"):
        step(eng, window(0, 0), window(-3, 0))  # outside the map
    with pytest.raises(ValueError, match="shape"):
        eng.step(np.zeros((1, 3), np.int64))
    assert not eng.invalid.any()
    cfg = eng.cfg
    lenient = EventEngine(cfg, 1, seed=0, invalid_action="stay")
    lenient.reset()
    ev = lenient.step(np.array([[window(-3, 0), window(0, 3)]]))
    assert ev.event_ticks[0] == 1 and ev.active[0, 0]  # robot_0 stayed
    assert lenient.state.goal[0, 0].tolist() == [1, 1]
    assert lenient.invalid.tolist() == [[True, False]]  # flagged for this step only
    lenient.step(np.array([[window(0, 0), window(0, 0)]]))
    assert not lenient.invalid.any()


def test_invalid_cell_actions_raise_with_nothing_changed_or_become_stay():
    eng = engine(goal_mode="cell")
    w = eng.shape[1]
    before = eng.state.copy()
    with pytest.raises(ValueError, match="robot_1 .* masked: its goal cell \\(0, 0\\)"):
        step(eng, 1 * w + 5, 0)  # robot_0's goal is fine, robot_1's is a wall
    assert np.array_equal(eng.state.goal, before.goal) and eng.state.ticks[0] == before.ticks[0]
    lenient = EventEngine(eng.cfg, 1, seed=0, goal_mode="cell", invalid_action="stay")
    lenient.reset()
    start = lenient.state.pos[0, 1].tolist()
    lenient.step(np.array([[1 * w + 5, w * eng.shape[0]]]))  # robot_1: out of range
    assert lenient.invalid.tolist() == [[False, True]]
    assert lenient.state.goal[0, 0].tolist() == [1, 5] and lenient.state.goal[0, 1].tolist() == start


def test_layout_walls_are_walls():
    eng = engine()
    assert (eng.state.grid[0, 0] == WALL).all()


def test_max_ticks_pauses_between_events():
    """Stepping one tick at a time visits the same states as stepping event to event."""
    fast, slow = engine(), engine()
    a = np.array([[window(0, 3), window(0, 3)]])
    ev = fast.step(a)
    assert ev.event_ticks[0] == 3
    fast_rewards = ev.rewards[0].copy()
    ticks, total = 0, np.zeros(2)
    ev = slow.step(a, max_ticks=1)
    while True:
        ticks += int(ev.event_ticks[0])
        total += ev.rewards[0]
        if slow.active[0].any():
            break
        assert slow.masks[0].sum(-1).tolist() == [1, 1]  # paused: nobody decides
        ev = slow.step(np.zeros((1, 2), np.int64), max_ticks=1)
        assert ev.event_ticks[0] == 1
    assert ticks == 3 and np.array_equal(slow.state.pos, fast.state.pos)
    assert np.allclose(total, fast_rewards) and fast_rewards.sum() < 0  # per-call rewards add up
    with pytest.raises(ValueError, match="max_ticks"):
        slow.step(a, max_ticks=0)
