"""What robots remember of each other (``WorldState.heard_*``), its observation option
(``EnvConfig.teammate_memory``) and the planner that uses it (``rrt-relay``).

The rules: docs/design.md#communication-and-slam-noise.
"""

import numpy as np

from catmip_env import EnvConfig, make_config
from catmip_env.constants import CH_CLASS0, OBS_CLUE, OBS_HALF, OBS_ONE, TARGET_BIT
from catmip_env.engines.events import EventEngine
from catmip_env.planners.baselines import make_planner
from tests.env.helpers import preset_engine, random_actions


def _knows(st, b):
    tr, tc = st.target[b]
    return (st.belief[b, :, tr, tc] & TARGET_BIT) != 0


def _check_reset(st, worlds):
    """A new episode remembers nothing from the last: news only of the neighbours at t = 0."""
    for b in np.flatnonzero(worlds):
        same = st.comp[b][:, None] == st.comp[b][None, :]
        assert (st.heard_tick[b] == np.where(same, 0, -1)).all()


def test_news_is_first_hand_in_the_neighbourhood_shared_inside_it_and_never_older():
    rng = np.random.default_rng(5)
    eng = preset_engine("task3", num_worlds=6, seed=5, comm_sigma=2.0)
    st, n = eng.state, eng.num_robots
    _check_reset(st, np.ones(6, bool))
    relayed = False
    for _ in range(150):
        before, episode = st.heard_tick.copy(), st.episode.copy()
        eng.step(random_actions(rng, eng))
        for b in range(6):
            same = st.comp[b][:, None] == st.comp[b][None, :]
            assert (st.heard_tick[b][same] == st.ticks[b]).all()
            i, j = np.nonzero(same)
            assert (st.heard_pos[b, i, j] == st.pos[b, j]).all()
            assert (st.heard_knows[b, i, j] == _knows(st, b)[j]).all()
            assert (st.heard_tick[b][~same] < st.ticks[b]).all()
            for k in range(n):  # members hold the same news of everyone
                assert (st.heard_tick[b, k] == st.heard_tick[b, st.comp[b, k]]).all()
            if st.episode[b] == episode[b]:
                assert (st.heard_tick[b] >= before[b]).all()
                # news of j got fresher without meeting j: it came through a teammate
                relayed |= bool(((st.heard_tick[b] > before[b]) & ~same).any())
        if st.done.any():
            done = st.done.copy()
            eng.reset(worlds=done)
            _check_reset(st, done)
    assert relayed, "with sigma = 2 some news should travel through a third robot"


def test_memory_option_changes_only_the_teammate_channels_of_the_global_map():
    rng = np.random.default_rng(1)
    plain = preset_engine("task3", num_worlds=4, seed=1, comm_sigma=2.0)
    shown = preset_engine("task3", num_worlds=4, seed=1, comm_sigma=2.0, teammate_memory=True)
    channels = plain.obs_global.shape[2]
    c = channels - CH_CLASS0 - 1  # the teammates' class channels, then the own position
    remembered = set()
    for _ in range(120):
        actions = random_actions(rng, plain)
        plain.step(actions)
        shown.step(actions)
        for name in ("pos", "belief", "comp", "heard_tick", "rescue_tick"):
            assert np.array_equal(getattr(plain.state, name), getattr(shown.state, name)), name
        assert np.array_equal(plain.obs_local, shown.obs_local)
        others = np.r_[0:CH_CLASS0, CH_CLASS0 + c : channels]  # every channel but the teammates' classes
        assert np.array_equal(plain.obs_global[:, :, others], shown.obs_global[:, :, others])
        teammates = slice(CH_CLASS0, CH_CLASS0 + c)
        assert (shown.obs_global[:, :, teammates] >= plain.obs_global[:, :, teammates]).all()
        remembered |= set(np.unique(shown.obs_global[:, :, teammates]).tolist())
        for d in (plain, shown):
            if d.state.done.any():
                d.reset(worlds=d.state.done.copy())
    assert remembered <= {0, OBS_CLUE, OBS_HALF, OBS_ONE} and OBS_HALF in remembered


# The explorer (robot 1) sees the target at reset; the rescuer (robot 0) is far away and out of range.
CORRIDOR = """
##################
#0...............#
#................#
#...........1..T.#
##################
"""


def _corridor():
    cfg = EnvConfig(
        layout=CORRIDOR, team=("rescuer", "explorer"), comm_sigma=0.01, activation=(0, 0), horizon_ticks=100
    )
    eng = EventEngine(cfg, 1, seed=0, goal_mode="cell")
    eng.reset()
    st = eng.state
    assert st.found_tick[0] == 0 and not _knows(st, 0)[0] and eng.active[0, 1]
    return eng, cfg


def _explorer_goal(eng, planner):
    return divmod(int(planner.act(eng)[0, 1]), eng.shape[1])


def _nearest_goal_to(eng, cell) -> float:
    """The smallest squared distance from ``cell`` to a goal the explorer may choose (not a robot's cell)."""
    valid = eng.masks[0, 1].reshape(eng.shape) != 0
    valid[tuple(eng.state.pos[0].T)] = False
    return float(((np.argwhere(valid) - cell) ** 2).sum(axis=1).min())


def test_relay_explorer_carries_the_news_to_where_it_last_heard_of_an_uninformed_rescuer():
    eng, _ = _corridor()
    st = eng.state
    rescuer, explorer = st.pos[0, 0].copy(), st.pos[0, 1].copy()
    st.heard_tick[0, 1, 0], st.heard_pos[0, 1, 0], st.heard_knows[0, 1, 0] = 0, rescuer, False
    goal = np.array(_explorer_goal(eng, make_planner("rrt-relay", seed=0)))
    assert ((goal - rescuer) ** 2).sum() == _nearest_goal_to(eng, rescuer)  # as near the rescuer as it may
    assert np.hypot(*(goal - rescuer)) < np.hypot(*(explorer - rescuer)) - 2
    # a rescuer that knew the target when last heard of needs no news: RRT's own choice
    st.heard_knows[0, 1, 0] = True
    assert _explorer_goal(eng, make_planner("rrt-relay", seed=0)) == _explorer_goal(
        eng, make_planner("rrt", seed=0)
    )


def test_relay_explorer_that_finds_the_cell_empty_explores_on():
    eng, _ = _corridor()
    st = eng.state
    st.heard_tick[0, 1, 0], st.heard_knows[0, 1, 0] = 0, False
    st.heard_pos[0, 1, 0] = st.pos[0, 1] + [0, -1]  # last heard of next to where the explorer stands
    relay = make_planner("rrt-relay", seed=0)
    assert _explorer_goal(eng, relay) == _explorer_goal(eng, make_planner("rrt", seed=0))
    st.heard_pos[0, 1, 0] = st.pos[0, 0]  # the same news, now far away: given up until newer news
    assert _explorer_goal(eng, relay) == _explorer_goal(eng, make_planner("rrt", seed=0))
    st.heard_tick[0, 1, 0] = 1  # newer news of it
    goal = np.array(_explorer_goal(eng, relay))
    assert ((goal - st.pos[0, 0]) ** 2).sum() == _nearest_goal_to(eng, st.pos[0, 0])


def test_news_carries_the_goal_a_teammate_was_heading_for():
    """``heard_goal``: first hand, the goal the teammate has this tick; passed on with the news."""
    from catmip_env.engines.events import random_valid_actions

    eng = EventEngine(EnvConfig(map_size=20, team=("rescuer", "explorer", "explorer"), comm_sigma=2.0), 6,
                      seed=3, goal_mode="cell")  # fmt: skip
    eng.reset()
    st, rng = eng.state, np.random.default_rng(3)
    carried = False
    for _ in range(60):
        eng.step(random_valid_actions(eng.masks, rng))
        for b in np.flatnonzero(~st.done):
            same = st.comp[b][:, None] == st.comp[b][None, :]
            i, j = np.nonzero(same)
            assert (st.heard_goal[b, i, j] == st.goal[b, j]).all()
            heard = st.heard_tick[b] >= 0
            carried |= bool((heard & ~same & (st.heard_goal[b, ..., 0] >= 0)).any())
        if st.done.any():
            eng.reset(worlds=st.done.copy())
    assert carried, "news of a teammate out of range should still say where it was going"


def test_estimated_cells_move_from_the_news_toward_its_goal_at_the_teammates_speed():
    from catmip_env.kernels.comms import estimated_cells

    tick = np.array([[-1, 10], [10, 10]])  # robot 0 has no news of itself here; of robot 1 from tick 10
    pos = np.array([[[0, 0], [5, 2]], [[0, 0], [5, 2]]])
    goal = np.array([[[-1, -1], [5, 12]], [[-1, -1], [-1, -1]]])
    speed = np.array([1, 2])  # robot 1 takes two ticks a cell
    for now, expected in ((10, [5, 2]), (14, [5, 4]), (19, [5, 6]), (40, [5, 12])):
        est = estimated_cells(tick, pos, goal, np.int64(now), speed)
        assert est[0, 1].tolist() == expected
        assert est[1, 1].tolist() == [5, 2]  # without a goal: where it was
        assert est[0, 0].tolist() == [0, 0]  # without news: the cell as it is
    batched = estimated_cells(tick[None], pos[None], goal[None], np.array([14]), speed[None])
    assert batched[0, 0, 1].tolist() == [5, 4]


def test_heading_relay_looks_for_the_rescuer_along_its_way_and_the_option_shows_it_there():
    eng, cfg = _corridor()
    st = eng.state
    rescuer = st.pos[0, 0].copy()
    st.heard_tick[0, 1, 0], st.heard_pos[0, 1, 0], st.heard_knows[0, 1, 0] = 0, rescuer, False
    st.heard_goal[0, 1, 0] = [1, 9]  # heading east along the top row, two ticks a cell
    st.ticks[0] = 12  # six cells along by now
    ahead = np.array([1, 7])
    goal = np.array(_explorer_goal(eng, make_planner("rrt-relay-heading", seed=0)))
    assert ((goal - ahead) ** 2).sum() == _nearest_goal_to(eng, ahead)
    plain = np.array(_explorer_goal(eng, make_planner("rrt-relay", seed=0)))
    assert ((plain - rescuer) ** 2).sum() == _nearest_goal_to(eng, rescuer)  # rrt-relay: where it was
    # the observation option draws the remembered rescuer at the same estimate (its class channel)
    shown = EventEngine(cfg.replace(teammate_memory=True, teammate_heading=True), 1, seed=0, goal_mode="cell")
    shown.reset()
    for name in ("heard_tick", "heard_pos", "heard_knows", "heard_goal", "ticks"):
        getattr(shown.state, name)[:] = getattr(st, name)
    shown.world.observe(np.ones(1, bool))
    rescuer_channel = shown.obs_global[0, 1, CH_CLASS0 + shown.state.cls[0, 0]]
    assert rescuer_channel[tuple(ahead)] == OBS_CLUE and rescuer_channel[tuple(rescuer)] == 0


def test_heading_needs_the_memory():
    import pytest

    with pytest.raises(ValueError, match="teammate_heading .* set teammate_memory too"):
        EnvConfig(teammate_heading=True)


def test_a_neighbourhood_that_decides_together_hears_its_members_new_goals():
    from catmip_env.kernels.activation import M_ACTIVE, M_FIELDS, assign_goals

    n = 3
    goal_cells = np.array([[[2, 3], [4, 5], [6, 7]]])
    goal = np.full((1, n, 2), -1)
    mstate = np.zeros((1, n, M_FIELDS), np.int64)
    mstate[0, :2, M_ACTIVE] = 1  # robots 0 and 1 decide; robot 2 is busy
    comp = np.array([[0, 2, 2]])  # robot 0 alone; robots 1 and 2 together
    heard_goal = np.full((1, n, n, 2), -1)
    assign_goals(np.ones(1, bool), goal_cells, goal, mstate, np.zeros((1, n)), comp, heard_goal)
    assert goal[0, :2].tolist() == [[2, 3], [4, 5]] and goal[0, 2].tolist() == [-1, -1]
    assert heard_goal[0, 0, 0].tolist() == [2, 3]  # its own
    assert heard_goal[0, 1, 1].tolist() == heard_goal[0, 2, 1].tolist() == [4, 5]  # its neighbourhood's
    assert heard_goal[0, 0, 1].tolist() == heard_goal[0, 1, 0].tolist() == [-1, -1]  # not the others'
    assert (heard_goal[0, :, 2] == -1).all()  # a busy robot chose nothing new


def test_coordinated_rrt_leaves_the_frontier_a_teammate_is_heading_for():
    """rrt-relay-coord is rrt-relay-heading until a robot has heard of a teammate's goal; then it leaves the
    cluster there to that teammate (same seeds, so the same trees)."""
    eng = EventEngine(make_config("task2", activation=(0, 0)), 8, seed=5, goal_mode="cell")
    eng.reset()
    st = eng.state
    st.heard_goal[:] = -1  # no news of any goal yet
    plain = make_planner("rrt-relay-heading", seed=0).act(eng)
    assert np.array_equal(make_planner("rrt-relay-coord", seed=0).act(eng), plain)
    w = eng.shape[1]
    for b, i in zip(*np.nonzero(eng.active)):
        j = (i + 1) % st.pos.shape[1]  # robot i heard that j heads for the cell i would have chosen
        st.heard_tick[b, i, j], st.heard_goal[b, i, j] = 0, divmod(int(plain[b, i]), w)
    coord = make_planner("rrt-relay-coord", seed=0).act(eng)
    away = []
    for b, i in zip(*np.nonzero(eng.active)):
        if coord[b, i] != plain[b, i]:
            away.append(np.hypot(*np.subtract(divmod(int(coord[b, i]), w), divmod(int(plain[b, i]), w))))
    assert len(away) >= 0.75 * eng.active.sum() and min(away) >= 3  # elsewhere, not next door
