"""The episode loop and the episode metrics (catmip_env.play), and the episode renderer built on them."""

import subprocess
import sys

import numpy as np
import pytest

from catmip_env import make_config
from catmip_env.engines.episode_stats import (
    DecisionTracker,
    EpisodeRecords,
    decision_metrics,
    episode_metrics,
    episode_records,
    success_curve,
)
from catmip_env.engines.events import EventEngine, random_valid_actions
from catmip_env.envs.render import episode_frames, episode_status
from catmip_env.planners.baselines import make_planner
from catmip_env.play import play


def _records(rescue, found, explored, decisions, stalls, cls=(0, 1), informed=None) -> EpisodeRecords:
    b = len(rescue)
    return EpisodeRecords(
        rescue_tick=np.array(rescue, np.int64),
        found_tick=np.array(found, np.int64),
        informed_tick=np.array(found if informed is None else informed, np.int64),
        explored_fraction=np.array(explored, np.float64),
        ticks=np.where(np.array(rescue) >= 0, rescue, 99).astype(np.int64),
        events=np.ones(b, np.int64),
        decisions=np.array(decisions, np.int64),
        stalls=np.array(stalls, np.int64),
        cls=np.tile(np.array(cls, np.int64), (b, 1)),
    )


HAND = _records(
    rescue=[-1, 3, 3, 5],
    found=[2, 1, -1, 4],
    explored=[0.5, 0.25, 1.0, 0.25],
    decisions=[[2, 1], [1, 1], [3, 0], [0, 0]],
    stalls=[[1, 0], [0, 0], [1, 0], [0, 0]],
    informed=[-1, 2, -1, 4],  # episode 0: the rescuer never heard; 1: a tick after the sighting
)


def test_success_curve_counts_rescues_by_tick():
    np.testing.assert_array_equal(success_curve(np.array([-1, 3, 3, 5]), 5), [0, 0, 0, 0.5, 0.5, 0.75])
    # a rescue after the horizon counts at the horizon; no episode at all is an empty success
    np.testing.assert_array_equal(success_curve(np.array([7, -1]), 3), [0, 0, 0, 0.5])
    np.testing.assert_array_equal(success_curve(np.array([], np.int64), 2), [0, 0, 0])


def test_episode_metrics_on_hand_built_records():
    m = episode_metrics(HAND, horizon=5)
    assert m == {
        "episodes": 4,
        "horizon": 5,
        "success_rate": 0.75,
        "success_by_100": 0.75,  # the horizon is shorter than 100 ticks
        "mean_rescue_tick": pytest.approx(11 / 3),
        "mean_target_found_tick": pytest.approx(7 / 3),
        "target_found_rate": 0.75,
        "mean_found_to_informed_ticks": 0.5,  # episodes 1 (2 - 1) and 3 (4 - 4)
        "mean_informed_to_rescue_ticks": 1.0,  # episodes 1 (3 - 2) and 3 (5 - 4)
        "mean_explored_fraction": 0.5,
        "decisions": 8,
    }
    assert list(m) == [
        "episodes", "horizon", "success_rate", "success_by_100", "mean_rescue_tick",
        "mean_target_found_tick", "target_found_rate", "mean_found_to_informed_ticks",
        "mean_informed_to_rescue_ticks", "mean_explored_fraction", "decisions",
    ]  # fmt: skip


def test_success_by_100_and_episodes_without_rescue_or_sighting():
    late = _records([-1, 100, 101, 300], [5, 5, 5, 5], [0, 0, 0, 0], [[1, 1]] * 4, [[0, 0]] * 4)
    m = episode_metrics(late, horizon=300)
    assert m["success_rate"] == 0.75 and m["success_by_100"] == 0.25
    assert m["mean_rescue_tick"] == pytest.approx(501 / 3)
    none = _records([-1, -1], [-1, -1], [0.2, 0.4], [[1, 1]] * 2, [[0, 0]] * 2)
    m = episode_metrics(none, horizon=300)
    assert m["success_rate"] == m["success_by_100"] == m["target_found_rate"] == 0.0
    assert m["mean_rescue_tick"] is None and m["mean_target_found_tick"] is None
    assert m["mean_found_to_informed_ticks"] is None and m["mean_informed_to_rescue_ticks"] is None
    assert m["mean_explored_fraction"] == pytest.approx(0.3)


def test_decision_metrics_on_hand_built_records():
    m = decision_metrics(HAND, make_config("task1").classes)  # class 0 rescuer, class 1 explorer
    assert m["decisions_per_episode"] == 8 / 4 and m["stalls_per_episode"] == 2 / 4
    # rescuers: decisions 2, 1, 3, 0 end 1 + 0 + 2 macro-actions, 2 of them stalled
    assert m["stalls_per_episode_rescuer"] == 2 / 4 and m["stall_fraction_rescuer"] == 2 / 3
    # explorers: every decision is its robot's last, so none has ended
    assert m["stalls_per_episode_explorer"] == 0 and np.isnan(m["stall_fraction_explorer"])


def _engine(worlds=3, seed=7, goal_mode="cell", **overrides) -> EventEngine:
    eng = EventEngine(make_config("task1", **overrides), worlds, seed=seed, goal_mode=goal_mode)
    eng.reset(episode_indices=np.arange(worlds))
    return eng


def _hand_rolled(eng: EventEngine, act) -> dict[str, np.ndarray]:
    """The loop written out, reading each world's outcome at the event its episode ended."""
    tracker = DecisionTracker(eng.num_worlds, eng.num_robots)
    tracker.reset(eng)
    events = np.zeros(eng.num_worlds, np.int64)
    explored = np.zeros(eng.num_worlds)
    while not eng.state.done.all():
        live = ~eng.state.done
        events += live
        tracker.before_step(eng)
        eng.step(act(eng))
        explored = np.where(live, eng.world.explored_fraction(), explored)
    st = eng.state
    return {
        "rescue_tick": st.rescue_tick.copy(),
        "found_tick": st.found_tick.copy(),
        "explored_fraction": explored,
        "ticks": st.ticks.copy(),
        "events": events,
        "decisions": tracker.decisions.copy(),
        "stalls": tracker.stalls.copy(),
        "cls": st.cls.copy(),
    }


@pytest.mark.parametrize("policy", ["nearest", "random-valid"])
def test_play_equals_the_loop_written_out(policy):
    def make():  # the same policy, in the same state, for both loops
        if policy == "nearest":
            return _engine(), make_planner("nearest", seed=0).act
        rng = np.random.default_rng(3)
        return _engine(4, goal_mode="window", activation=(0, 0)), lambda e: random_valid_actions(e.masks, rng)

    eng, act = make()
    got = play(eng, act)
    eng2, act2 = make()
    want = _hand_rolled(eng2, act2)
    for key, value in want.items():
        np.testing.assert_array_equal(getattr(got, key), value, err_msg=key)
    assert eng.state.done.all() and (got.events > 0).all() and got.decisions.sum() > 0
    # the records are copies: a new episode leaves them alone
    before = got.rescue_tick.copy()
    eng.reset()
    np.testing.assert_array_equal(got.rescue_tick, before)


def test_play_accepts_a_policy_object_and_reports_every_event():
    eng = _engine()
    seen = []
    records = play(eng, make_planner("rrt", seed=1), on_event=lambda e: seen.append(int(e.state.done.sum())))
    assert len(seen) == records.events.max()  # the loop runs until the longest episode ends
    assert seen == sorted(seen) and seen[-1] == eng.num_worlds
    m = episode_metrics(records, eng.cfg.horizon_ticks)
    assert m["success_rate"] == records.rescued.mean() and m["episodes"] == 3


def test_until_stops_early_and_max_ticks_pauses_after_every_tick():
    eng = _engine(1)
    records = play(eng, make_planner("nearest").act, until=lambda e: e.state.ticks[0] >= 5, max_ticks=1)
    # one tick per step: 5 steps, and the episode is not over
    assert records.ticks[0] == 5 and records.events[0] == 5 and not eng.state.done[0]
    again = episode_records(eng)  # without a tracker: decisions, stalls and events are zeros
    assert again.ticks[0] == 5 and again.decisions.sum() == 0 and again.events.sum() == 0


def test_episode_frames_one_per_tick_until_the_end_or_max_frames():
    eng = EventEngine(make_config("task1"), 1, seed=0, goal_mode="cell")
    frames = episode_frames(eng, make_planner("nearest"), episode=2, max_frames=6, caption=False)
    assert len(frames) == 6 and frames[0].shape == (15 * 16, 15 * 16, 3) and frames[0].dtype == np.uint8
    assert eng.state.ticks[0] == 5 and not eng.state.done[0]
    frames = episode_frames(eng, make_planner("nearest"), episode=2, max_frames=10_000)
    assert eng.state.done[0] and len(frames) == eng.state.ticks[0] + 1
    # captioned: the map, then a strip of one shape in every frame, whose text changes with the tick
    assert {f.shape for f in frames} == {frames[0].shape} and frames[0].shape[0] > 15 * 16
    strips = [f[15 * 16 :] for f in frames]
    assert not np.array_equal(strips[0], strips[1]) and not np.array_equal(strips[-2], strips[-1])


def test_the_caption_says_the_tick_and_how_the_mission_stands():
    eng = EventEngine(make_config("task1"), 1, seed=0, goal_mode="cell")
    eng.reset(episode_indices=[2])
    assert episode_status(eng.world) == "tick 0 / 300 · searching"
    seen = []
    play(eng, make_planner("nearest"), on_event=lambda e: seen.append(episode_status(e.world)), max_ticks=1)
    st = eng.state
    assert st.rescue_tick[0] > st.found_tick[0] >= 0
    assert f"tick {st.found_tick[0]} / 300 · target found at tick {st.found_tick[0]}" in seen or (
        st.informed_tick[0] == st.found_tick[0]
    )
    assert seen[-1] == f"tick {st.rescue_tick[0]} / 300 · RESCUED at tick {st.rescue_tick[0]}"
    st.rescue_tick[0], st.done[0] = -1, True
    assert episode_status(eng.world).endswith("NOT RESCUED by the horizon (300 ticks)")


def test_play_is_torch_free():
    code = "import sys, catmip_env.play, catmip_env.envs.render; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def _first_informed(eng, advance, max_steps: int) -> np.ndarray:
    """Step ``advance()`` (one tick each) and return each world's first tick at which a robot that
    can rescue had the target in its belief (-1 if none), read from the state after every tick."""
    from catmip_env.constants import TARGET_BIT

    b = np.arange(eng.num_worlds)[:, None]
    n = np.arange(eng.num_robots)[None, :]
    first = np.full(eng.num_worlds, -1)
    for _ in range(max_steps):
        if eng.state.done.all():
            break
        live = ~eng.state.done
        advance()
        st = eng.state
        target = st.belief[b, n, st.target[:, None, 0], st.target[:, None, 1]]
        knows = ((target & TARGET_BIT) != 0) & st.can_rescue
        first = np.where(live & (first < 0) & knows.any(1), st.ticks, first)
    return first


def test_informed_tick_is_the_first_tick_a_rescuer_knows_the_target():
    """Tick by tick, with short-range communication so that the news often reaches the rescuer after
    the sighting: on the primitive engine (the tick kernel: random walks on a two-room map whose
    target is in the far room) and on the event engine (the macro kernel, Nearest's goals, paused
    after every tick)."""
    from catmip_env import BatchedWorld

    from .helpers import TWO_ROOMS, layout_config

    eng = BatchedWorld(layout_config(TWO_ROOMS, comm_sigma=1.0, horizon_ticks=3000), num_worlds=8, seed=5)
    eng.reset()
    rng = np.random.default_rng(0)
    first = _first_informed(eng, lambda: eng.step(rng.integers(0, 4, size=(8, 2))), 3000)
    np.testing.assert_array_equal(eng.state.informed_tick, first)
    found, informed = eng.state.found_tick, eng.state.informed_tick
    assert (informed >= found).all() and (informed > found).any() and (found > 0).all()

    ev = EventEngine(make_config("task2", comm_sigma=2.0), num_worlds=8, seed=1, goal_mode="cell")
    ev.reset()
    planner = make_planner("nearest", seed=0)
    first = _first_informed(ev, lambda: ev.step(planner.act(ev), max_ticks=1), 1000)
    np.testing.assert_array_equal(ev.state.informed_tick, first)
    assert (ev.state.informed_tick > ev.state.found_tick).any()
    ev = EventEngine(make_config("task2"), num_worlds=8, seed=1)  # full communication
    ev.reset()
    records = play(ev, lambda e: random_valid_actions(e.masks, rng))
    assert (records.informed_tick[records.found] == records.found_tick[records.found]).all()
    assert (records.rescue_tick[records.rescued] >= records.informed_tick[records.rescued]).all()
