"""Decision and stall counts (catmip_env.engines.episode_stats)."""

import numpy as np

from catmip_env import make_config
from catmip_env.engines.episode_stats import DecisionTracker
from catmip_env.engines.events import EventEngine
from catmip_env.planners.window import make_window_planner


def _play(policy, worlds=4, **overrides):
    eng = EventEngine(make_config("task1", activation=(0, 0), **overrides), worlds, 0)
    eng.reset()
    tracker = DecisionTracker(eng.num_worlds, eng.num_robots)
    tracker.reset(eng)
    while not eng.state.done.all():
        tracker.before_step(eng)
        eng.step(policy(eng))
    return eng, tracker


def test_a_robot_that_always_stays_stalls_at_every_decision_but_the_first():
    eng, tracker = _play(lambda e: np.full((e.num_worlds, e.num_robots), e.stay_action), horizon_ticks=30)
    # a stay goal ends after one tick and activation (0, 0) decides again at once: one decision a tick
    assert (tracker.decisions == 30).all()
    assert (tracker.stalls == tracker.decisions - 1).all()
    s = tracker.summary(eng.state.cls, eng.cfg.classes)
    assert s["decisions_per_episode"] == 60 and s["stalls_per_episode"] == 58
    assert s["stall_fraction_rescuer"] == s["stall_fraction_explorer"] == 1.0  # every ended one stalled


def test_a_planner_that_moves_rarely_stalls():
    teacher = make_window_planner("nearest")
    eng, tracker = _play(teacher.act)
    s = tracker.summary(eng.state.cls, eng.cfg.classes)
    assert s["decisions_per_episode"] > 4
    assert s["stalls_per_episode"] < 0.25 * s["decisions_per_episode"]
    tracker.reset(eng, np.array([0]))
    assert tracker.decisions[0].sum() == 0 and tracker.decisions[1:].sum() > 0
