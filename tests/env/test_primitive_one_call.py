"""The primitive level's one-call step (the tick, the observations and the infos in one kernel call; the
actions taken as given when they are plain ints in range) shows what the world holds: every format's
observations equal the engine's own maps and state, the infos its read-outs, whatever the actions."""

import numpy as np
import pytest

from catmip_env import BatchedWorld, make_config, search_rescue_v0
from catmip_env.kernels.primitive import DirectCall, tick_and_observe

VARIANTS = {
    "task2": ("task2", {}),
    "task3, comm and noise": ("task3", {"comm_sigma": 2.0, "slam_noise": 0.05}),
    "memory and heading": ("task2", {"comm_sigma": 2.0, "teammate_memory": True, "teammate_heading": True}),
}
FORMATS = {"dict": {}, "compact": {"compact_obs": True}, "flat": {"obs_format": "flat"}}


def _actions(rng, agents, k):
    """Plain ints, numpy ints, an out-of-range one, floats: the quick path and the parsed one."""
    drawn = rng.integers(4, size=len(agents)).tolist()
    kind = k % 4
    if kind == 1:
        return {a: np.int64(v) for a, v in zip(agents, drawn)}, 0
    if kind == 2:
        return {a: (7 if i == 0 else v) for i, (a, v) in enumerate(zip(agents, drawn))}, 1
    if kind == 3:
        return {a: float(v) for a, v in zip(agents, drawn)}, 0
    return dict(zip(agents, drawn)), 0


def _expected(env, bad: np.ndarray, counts: np.ndarray):
    """The observation parts and infos of robot i, read from the engine (not from the env's view)."""
    world, st = env.world, env.world.state
    knows = world.knows_target()[0]
    t = int(st.ticks[0])
    for i, agent in enumerate(env.possible_agents):
        parts = {
            "global_map": world.obs_global[0, i].astype(np.float32) * np.float32(0.25),
            "local_map": world.obs_local[0, i].astype(np.float32) * np.float32(0.25),
            "agent_class": np.eye(env.config.num_classes, dtype=np.float32)[st.cls[0, i]],
            "heading": np.eye(4, dtype=np.float32)[st.heading[0, i]],
        }
        info = {
            "agent_class": int(st.cls[0, i]),
            "tick": t,
            "neighbourhood": int(st.comp[0, i]),
            "can_act": int(t % st.speed[0, i] == 0),
            "knows_target": int(knows[i]),
            "invalid_action": int(bad[i]),
            "invalid_actions": int(counts[i]),
        }
        yield i, agent, parts, info


def _check(envs, obs, infos, bad, counts):
    for _, agent, parts, info in _expected(envs["dict"], bad, counts):
        for key, want in parts.items():
            got = obs["dict"][agent]["observation"][key]
            assert got.dtype == np.float32
            np.testing.assert_array_equal(got, want, err_msg=key)
            compact = obs["compact"][agent]["observation"][key]
            np.testing.assert_array_equal(compact.astype(np.float32) * (0.25 if "map" in key else 1), want)
            where, shape = envs["flat"].flat_layout[key]
            np.testing.assert_array_equal(obs["flat"][agent][where].reshape(shape), want)
        assert infos["dict"][agent] == infos["compact"][agent] == info
        assert {k: v for k, v in infos["flat"][agent].items() if k != "action_mask"} == info
        for name in FORMATS:
            mask = (
                obs["dict"][agent]["action_mask"] if name == "dict" else infos["flat"][agent]["action_mask"]
            )
            np.testing.assert_array_equal(mask, np.ones(4, np.int8))


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_every_format_shows_what_the_engine_holds(variant):
    preset, kw = VARIANTS[variant]
    envs = {
        name: search_rescue_v0.parallel_env(preset=preset, level="primitive", max_cycles=60, **kw, **extra)
        for name, extra in FORMATS.items()
    }
    rng = np.random.default_rng(5)
    n = len(envs["dict"].possible_agents)
    for episode in range(2):
        out = {name: e.reset(seed=3 if episode == 0 else None) for name, e in envs.items()}
        bad, counts = np.zeros(n, int), np.zeros(n, int)
        k = 0
        while envs["dict"].agents:
            _check(envs, {m: o[0] for m, o in out.items()}, {m: o[-1] for m, o in out.items()}, bad, counts)
            acts, flagged = _actions(rng, envs["dict"].possible_agents, k)
            bad = np.zeros(n, int)
            bad[0] = flagged
            counts += bad
            out = {name: e.step(dict(acts)) for name, e in envs.items()}
            assert out["dict"][1:4] == out["compact"][1:4] == out["flat"][1:4]  # rewards, ends
            k += 1
        assert counts[0] >= 10  # the replaced actions' flags were checked too


def test_an_out_of_range_action_changes_nothing_and_names_the_robot():
    world = BatchedWorld(make_config("task2"), num_worlds=2, seed=0)
    world.reset()
    before = world.state.copy()
    actions = np.zeros((2, 3), np.int64)
    actions[1, 2] = 4
    with pytest.raises(ValueError, match=r"primitive action 4 of robot_2 in world 1 is out of range"):
        world.step(actions)
    for name, a in vars(before).items():
        np.testing.assert_array_equal(a, getattr(world.state, name), err_msg=name)
    with pytest.raises(ValueError, match="must have shape"):
        world.step(np.zeros((2, 2), np.int64))
    with pytest.raises(ValueError, match="must be integers"):
        world.step(np.zeros((2, 3)))


def test_the_batched_step_takes_any_integer_layout():
    """A strided or int32 action array is taken as the same actions (copied into the kernel's layout)."""
    worlds = [BatchedWorld(make_config("task2"), num_worlds=4, seed=1) for _ in range(2)]
    for w in worlds:
        w.reset()
    rng = np.random.default_rng(0)
    for _ in range(30):
        a = rng.integers(0, 4, size=(4, 6))
        worlds[0].step(a[:, ::2].astype(np.int32)[:, :])  # int32
        worlds[1].step(np.ascontiguousarray(a[:, ::2]))
        worlds[0].step(a[:, 1::2])  # strided int64
        worlds[1].step(np.ascontiguousarray(a[:, 1::2]))
        np.testing.assert_array_equal(worlds[0].obs_global, worlds[1].obs_global)
        np.testing.assert_array_equal(worlds[0].state.belief, worlds[1].state.belief)


def test_a_direct_call_is_the_kernel_called_through_numba():
    worlds = [BatchedWorld(make_config("task2"), num_worlds=1, seed=2) for _ in range(2)]
    for w in worlds:
        w.reset()
    direct = DirectCall(tick_and_observe)
    calls = (direct, tick_and_observe)

    def args(w, a):
        outs = np.zeros((1, 3)), np.zeros(1, bool), np.zeros(1, bool)
        return ~w.state.done, a, w.state.kernel, w.rules, *outs, False, False, w.obs_global, w.obs_local

    for t in range(20):
        a = np.full((1, 3), t % 4, np.int64)
        assert [call(*args(w, a)) for call, w in zip(calls, worlds)] == [-1, -1]
        np.testing.assert_array_equal(worlds[0].obs_global, worlds[1].obs_global)
    assert direct(*args(worlds[0], np.full((1, 3), 9, np.int64))) == 0  # robot 0's action is out of range


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_a_pickled_env_steps_as_the_original(fmt):
    """Pickled mid-episode (the kernels' compiled entries are left out and found again), the copy steps
    exactly as the env it was made from."""
    import pickle

    env = search_rescue_v0.parallel_env(preset="task2", level="primitive", comm_sigma=2.0, **FORMATS[fmt])
    env.reset(seed=4)
    env.step({a: 2 for a in env.agents})
    copy = pickle.loads(pickle.dumps(env))
    for k in range(40):
        acts = {a: (k + i) % 4 for i, a in enumerate(env.agents)}
        (o1, r1, *_, i1), (o2, r2, *_, i2) = env.step(acts), copy.step(acts)
        assert r1 == r2
        for a in env.agents:
            np.testing.assert_equal(o1[a], o2[a])
            np.testing.assert_equal(i1[a], i2[a])
