"""threads=: the worlds split over threads step exactly as on one thread (a world depends only on its
seed, episode and actions), in both goal modes, with SLAM noise, drawn communication and resets."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from catmip_env import BatchedWorld, EventEngine, make_config
from catmip_env.engines.chunks import WorldChunks
from catmip_env.engines.events import random_valid_actions
from catmip_env.kernels.state import WorldState

FIELDS = WorldState.__dataclass_fields__


def _snapshot(engine) -> dict[str, np.ndarray]:
    st = engine.state
    out = {f: getattr(st, f).copy() for f in FIELDS}
    out |= {"obs_global": engine.obs_global.copy(), "obs_local": engine.obs_local.copy()}
    if isinstance(engine, EventEngine):
        out |= {"masks": engine.masks.copy(), "mstate": engine.mstate.copy()}
    return out


def _same(a: dict, b: dict) -> None:
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


@pytest.mark.parametrize(("goal_mode", "preset", "overrides"), [
    ("window", "task2", {"slam_noise": 0.05, "comm_sigma_choices": [None, 4, 2]}),
    ("cell", "task3", {"activation": [2, 5]}),
])  # fmt: skip
def test_an_event_engine_on_threads_steps_exactly_as_on_one(goal_mode, preset, overrides):
    cfg = make_config(preset, **overrides)
    engines = [EventEngine(cfg, num_worlds=7, seed=3, goal_mode=goal_mode, threads=t) for t in (1, 3)]
    assert [e.world.chunks.threads for e in engines] == [1, 3]
    rng = [np.random.default_rng(0), np.random.default_rng(0)]
    for e in engines:
        e.reset()
    for _ in range(60):
        results = []
        for e, g in zip(engines, rng):
            res = e.step(random_valid_actions(e.masks, g))
            results.append(
                (res.rewards.copy(), res.event_ticks.copy(), res.terminated.copy(), res.truncated.copy())
            )
            if e.state.done.any():
                e.reset(worlds=e.state.done)
        for x, y in zip(*results):
            np.testing.assert_array_equal(x, y)
        _same(*[_snapshot(e) for e in engines])


@pytest.mark.parametrize("heading", [False, True], ids=["one-call-chunks", "heading-estimate"])
@pytest.mark.parametrize("split_work", [0, None], ids=["split", "too-little-work-to-split"])
def test_a_batched_world_on_threads_ticks_exactly_as_on_one(split_work, heading, monkeypatch):
    """On two threads (the tick split however little work it is) or on the caller's (too little work
    to be worth a second thread: ``TICK_SPLIT_WORK``), the same worlds as on one; a chunk's tick and
    observations in one kernel call, or (teammates drawn at their estimated cells) in two."""
    import catmip_env.engines.world

    if split_work is not None:
        monkeypatch.setattr(catmip_env.engines.world, "TICK_SPLIT_WORK", split_work)
    cfg = make_config("task2", slam_noise=0.05, teammate_memory=heading, teammate_heading=heading)
    worlds = [BatchedWorld(cfg, num_worlds=5, seed=1, threads=t) for t in (1, 2)]
    for w in worlds:
        w.reset()
    rng = np.random.default_rng(1)
    for _ in range(50):
        actions = rng.integers(0, 4, size=(5, cfg.num_robots))
        for w in worlds:
            w.step(actions)
        _same(*[_snapshot(w) for w in worlds])


def test_threads_are_checked_and_capped_at_the_worlds():
    with pytest.raises(ValueError, match="threads must be an int >= 1"):
        BatchedWorld(make_config("task1"), num_worlds=2, threads=0)
    assert BatchedWorld(make_config("task1"), num_worlds=2, threads=8).chunks.threads == 2


def test_chunks_run_only_those_that_hold_a_named_world():
    chunks = WorldChunks(9, threads=3)
    assert chunks.slices == [slice(0, 3), slice(3, 6), slice(6, 9)]
    ran, caller = [], threading.get_ident()
    named = np.zeros(9, np.bool_)
    named[[4, 7]] = True
    chunks.run(lambda w: ran.append(w), named)
    assert sorted(w.start for w in ran) == [3, 6]
    ran.clear()
    named[7] = False  # one chunk left: it runs on the caller's thread
    chunks.run(lambda w: ran.append((w, threading.get_ident())), named)
    assert ran == [(slice(3, 6), caller)]
    with pytest.raises(RuntimeError, match="boom"):  # a chunk's error reaches the caller
        chunks.run(lambda w: (_ for _ in ()).throw(RuntimeError("boom")) if w.start == 6 else None)


def test_a_bad_action_on_split_threads_is_refused_before_any_world_moves(monkeypatch):
    import catmip_env.engines.world

    monkeypatch.setattr(catmip_env.engines.world, "TICK_SPLIT_WORK", 0)
    cfg = make_config("task2")
    w = BatchedWorld(cfg, num_worlds=6, seed=2, threads=2)
    w.reset()
    before = _snapshot(w)
    actions = np.zeros((6, cfg.num_robots), np.int64)
    actions[4, 1] = 7  # in the second thread's chunk
    with pytest.raises(ValueError, match="primitive action 7 of robot_1 in world 4 is out of range"):
        w.step(actions)
    _same(before, _snapshot(w))


def test_a_pickled_world_on_threads_steps_as_the_one_it_was_made_from(monkeypatch):
    """The workers stay behind (started again in the copy), and so do the state's chunk views (a
    pickled view would come back a detached copy: the copy's threads would write into it)."""
    import pickle

    import catmip_env.engines.world

    monkeypatch.setattr(catmip_env.engines.world, "TICK_SPLIT_WORK", 0)
    cfg = make_config("task3")
    a = BatchedWorld(cfg, num_worlds=6, seed=5, threads=2)
    a.reset()
    a.step(np.ones((6, cfg.num_robots), np.int64))  # workers started, chunk views built
    b = pickle.loads(pickle.dumps(a))
    rng = np.random.default_rng(3)
    for _ in range(40):
        actions = rng.integers(0, 4, size=(6, cfg.num_robots))
        for w in (a, b):
            w.step(actions)
            if w.state.done.any():
                w.reset(worlds=w.state.done)
    _same(_snapshot(a), _snapshot(b))


def test_a_chunk_runs_on_a_worker_thread_that_ends_with_its_chunks():
    import gc

    chunks = WorldChunks(4, threads=2)
    ran = {}
    chunks.run(lambda w: ran.setdefault(w.start, threading.current_thread()))
    worker = ran[2]
    assert worker is not threading.current_thread() and worker.daemon and worker.is_alive()
    chunks.run(lambda w: ran.setdefault(-w.start, threading.current_thread()))
    assert ran[-2] is worker  # the same worker again, not a new thread each step
    del chunks
    gc.collect()
    worker.join(timeout=5)
    assert not worker.is_alive()


def _step_in_child(world, actions, out):
    world.step(actions)
    out.put(world.state.pos.copy())


def test_a_forked_copy_of_a_world_on_threads_starts_its_own_workers(monkeypatch):
    """A fork copies the parent's workers as objects, not as threads: the child must not wait on them."""
    import multiprocessing

    import catmip_env.engines.world

    monkeypatch.setattr(catmip_env.engines.world, "TICK_SPLIT_WORK", 0)
    cfg = make_config("task2")
    w = BatchedWorld(cfg, num_worlds=6, seed=4, threads=2)
    w.reset()
    actions = np.ones((6, cfg.num_robots), np.int64)
    w.step(actions)  # the parent's worker is running
    ctx = multiprocessing.get_context("fork")
    out = ctx.Queue()
    child = ctx.Process(target=_step_in_child, args=(w, actions, out), daemon=True)
    child.start()
    try:
        pos = out.get(timeout=60)  # a child waiting on the parent's worker would never answer
    finally:
        child.terminate()
        child.join(timeout=10)
    w.step(actions)
    np.testing.assert_array_equal(pos, w.state.pos)


def test_a_dropped_world_on_threads_is_freed_with_its_workers():
    """A worker keeps nothing of its last chunk: the chunk's function holds its world."""
    import gc
    import weakref

    before = threading.active_count()
    cfg = make_config("task2", teammate_memory=True, teammate_heading=True)
    refs = []
    for _ in range(4):
        w = BatchedWorld(cfg, num_worlds=4, seed=0, threads=2)
        w.reset()  # the workers' last job: a reset's chunk
        refs.append(weakref.ref(w))
        e = EventEngine(cfg, num_worlds=4, seed=0, threads=2)
        e.reset()
        e.step(random_valid_actions(e.masks, np.random.default_rng(0)))  # the last job: a step's chunk
        refs.append(weakref.ref(e))
    del w, e
    gc.collect()
    assert [r() for r in refs] == [None] * len(refs)
    for thread in threading.enumerate():
        if thread.name.startswith("catmip-worlds"):
            thread.join(timeout=5)
    assert threading.active_count() == before


def test_an_interrupt_while_a_worker_runs_is_raised_once_its_chunk_has_ended():
    """Ctrl-C while the caller waits: the worker is still writing its worlds; the interrupt is raised
    after that, and the next run waits for its own chunks again."""
    import os
    import signal
    import time

    chunks = WorldChunks(2, threads=2)
    out = np.zeros(2)

    def slow(w, value):
        if w.start == 1:
            time.sleep(0.5)
        out[w] = value

    def interrupt(signum, frame):  # Ctrl-C's, on a signal of our own (a test runner may own SIGINT's)
        raise KeyboardInterrupt

    chunks.run(lambda w: None)  # the worker started
    previous = signal.signal(signal.SIGUSR1, interrupt)
    timer = threading.Timer(0.1, os.kill, (os.getpid(), signal.SIGUSR1))
    try:
        timer.start()
        with pytest.raises(KeyboardInterrupt):
            chunks.run(lambda w: slow(w, 1.0))
        assert out.tolist() == [1.0, 1.0]  # raised only after the worker's chunk
    finally:
        timer.join()
        signal.signal(signal.SIGUSR1, previous)
    chunks.run(lambda w: slow(w, 2.0))
    assert out.tolist() == [2.0, 2.0]  # not returned before the worker's chunk ended


def test_a_run_inside_a_chunk_runs_every_chunk():
    chunks = WorldChunks(6, threads=3)
    seen, lock = [], threading.Lock()

    def outer(w):
        if w.start in (0, 2):  # from the caller's thread and from a worker's
            chunks.run(lambda inner: _record(seen, lock, (w.start, inner.start)))

    chunks.run(outer)
    assert sorted(seen) == [(0, 0), (0, 2), (0, 4), (2, 0), (2, 2), (2, 4)]
    seen.clear()
    chunks.run(lambda w: _record(seen, lock, w.start))  # later runs as before
    assert sorted(seen) == [0, 2, 4]


def _record(seen, lock, item):
    with lock:
        seen.append(item)
