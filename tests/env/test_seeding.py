"""A reset's random streams drawn in a kernel (catmip_env.kernels.seeding, .episodes) are numpy's, bit for
bit: the seed sequences, PCG64, Generator.random and .integers, and so every world a reset loads."""

import numpy as np
import pytest

import catmip_env.engines.world as world_module
from catmip_env import BatchedWorld, make_config
from catmip_env.engines.world import world_key
from catmip_env.kernels import mapgen
from catmip_env.kernels.rng import seed_state
from catmip_env.kernels.seeding import int_words, pcg64_integer, pcg64_stream, pcg64_uniforms, seed_words

# one-word to five-word seeds, one- and two-word episodes, the edges of a word, the largest episode
CASES = [(0, 0), (1, 2), (2**32 - 1, 7), (2**32, 3), (2**63 - 1, 2**32 + 5), (20261201, 2**62 - 1)]
CASES += [(2**63, 1), (2**64 - 1, 9), (2**64, 0), (3**80, 2**40)]
CASES += [(int(s), int(e)) for s, e in np.random.default_rng(5).integers(0, 2**62, size=(40, 2))]


@pytest.mark.parametrize("seed, episode", CASES)
def test_seed_words_are_numpys_seed_sequence(seed, episode):
    for child in (0, 1, 2):
        expected = np.random.SeedSequence(seed, spawn_key=(episode, child)).generate_state(3, np.uint64)
        assert np.array_equal(seed_words(int_words(seed), episode, child, 3), expected)


@pytest.mark.parametrize("seed, episode", CASES)
def test_a_pcg64_stream_draws_what_numpys_generator_draws(seed, episode):
    map_seq, _ = np.random.SeedSequence(seed, spawn_key=(episode,)).spawn(2)
    numpy_rng, g = np.random.default_rng(map_seq), pcg64_stream(int_words(seed), episode, 0)
    state = numpy_rng.bit_generator.state["state"]
    assert (int(g[0]) << 64 | int(g[1]), int(g[2]) << 64 | int(g[3])) == (state["state"], state["inc"])
    draws = np.random.default_rng(episode % 1000)
    # small ranges, one that draws nothing (n = 1), one that rejects half its draws (2**31 + 1), and
    # uniforms between them (the buffered 32-bit half must carry over)
    for n in [1, 2, 3, 5, 7, 2**31 + 1, 2**32 - 1, *draws.integers(1, 2**32, size=6)]:
        assert pcg64_integer(g, int(n)) == numpy_rng.integers(int(n))
        assert np.array_equal(pcg64_uniforms(g, 3), numpy_rng.random(3))
    assert np.array_equal(pcg64_uniforms(g, 200), numpy_rng.random(200))


def _python_world(cfg, seed, episode):
    """What the Python streams load for ``episode``: (map, dynamics state, world key, drawn range)."""
    eng = BatchedWorld(cfg, num_worlds=1, seed=seed)
    map_rng, dyn = eng.episode_streams(episode)
    ep = mapgen.generate(cfg, map_rng)
    ranges = cfg.comm_ranges
    pick = int(map_rng.integers(len(ranges))) if len(ranges) > 1 else 0
    return ep, dyn, world_key(seed, episode), 0.0 if ranges[pick] is None else float(ranges[pick])


CONFIGS = {
    "task2": dict(preset="task2"),
    "task3": dict(preset="task3"),
    "random slots and drawn ranges": dict(preset="train", comm_sigma_choices=(None, 2.0, 4.5)),
    "small map": dict(preset="task1", map_size=10, num_obstacles=12),
}


@pytest.mark.parametrize("name", list(CONFIGS))
@pytest.mark.parametrize("threads", [1, 2])
def test_a_reset_loads_the_worlds_the_python_streams_draw(name, threads, monkeypatch):
    monkeypatch.setattr(world_module, "perceive_at_reset", lambda *args: None)  # it draws from st.rng
    kw = dict(CONFIGS[name])
    cfg = make_config(kw.pop("preset"), **kw)
    episodes = np.array([0, 1, 2, 9, 2**40, 77, 3, 5], np.int64)
    seed = 2**33 + 17 if threads == 1 else 2**64 + 17  # any int >= 0, as numpy takes it
    w = BatchedWorld(cfg, num_worlds=len(episodes), seed=seed, threads=threads)
    w.reset(episode_indices=episodes)
    st = w.state
    for b, k in enumerate(episodes):
        ep, dyn, key, sigma = _python_world(cfg, seed, int(k))
        assert np.array_equal(st.grid[b], ep.grid) and np.array_equal(st.pos[b], ep.robots)
        assert np.array_equal(st.heading[b], ep.headings) and np.array_equal(st.cls[b], ep.classes)
        assert tuple(st.target[b]) == ep.target and st.rng[b] == dyn and w.world_keys[b] == key
        assert st.comm_sigma[b] == sigma and st.episode[b] == k and st.ticks[b] == 0
        speed = [cfg.classes[c].ticks_per_action for c in ep.classes]
        assert st.speed[b].tolist() == speed


def test_a_map_that_needs_a_bigger_block_goes_on_with_the_same_stream(monkeypatch):
    cfg = make_config("task3")
    for module in (mapgen, world_module):  # 16 uniforms: every map runs out and retries
        monkeypatch.setattr(module, "first_block", lambda _cfg: 16)
    w = BatchedWorld(cfg, num_worlds=4, seed=3)
    w.reset()
    for b in range(4):
        ep, dyn, _, _ = _python_world(cfg, 3, b)
        assert np.array_equal(w.state.grid[b], ep.grid) and tuple(w.state.target[b]) == ep.target
        assert w.state.rng[b] == dyn


def test_a_map_the_generator_cannot_draw_is_a_clear_error_and_leaves_its_world_as_it_was():
    cfg = make_config("task1", map_size=10, wall_prob=1.0, team=["explorer"] * 12)  # some episodes fail
    w = BatchedWorld(cfg, num_worlds=1, seed=0)
    for k in range(40):
        before = {f: getattr(w.state, f).copy() for f in ("grid", "pos", "heading", "target", "episode")}
        try:
            w.reset(episode_indices=[k])
        except ValueError as error:
            assert "spawn box of a 10x10 map has fewer free cells than 12 robots" in str(error)
            for f, v in before.items():
                np.testing.assert_array_equal(getattr(w.state, f), v, err_msg=f)
            return
    pytest.fail("no episode of 12 robots on a 10x10 map failed to spawn")


def test_the_dynamics_state_is_seed_state_of_the_dynamics_child():
    seq = np.random.SeedSequence(11, spawn_key=(4,)).spawn(2)[1]
    assert seed_words(int_words(11), 4, 1, 1)[0] == seed_state(seq)


def test_a_layouts_episodes_draw_their_random_slots_and_ranges_from_the_map_stream(monkeypatch):
    from catmip_env.ascii_maps import parse_layout

    from .helpers import TWO_ROOMS, layout_config

    monkeypatch.setattr(world_module, "perceive_at_reset", lambda *args: None)
    cfg = layout_config(TWO_ROOMS, team=("random", "explorer"), comm_sigma_choices=(None, 2.0, 3.0))
    lay, seed = parse_layout(TWO_ROOMS), 41
    w = BatchedWorld(cfg, num_worlds=6, seed=seed, threads=2)
    w.reset()
    drawn = set()
    for b in range(6):
        map_rng, dyn = w.episode_streams(b)
        first = cfg.class_index(cfg.random_classes[int(map_rng.integers(len(cfg.random_classes)))])
        sigma = cfg.comm_ranges[int(map_rng.integers(len(cfg.comm_ranges)))]
        st = w.state
        assert np.array_equal(st.grid[b], lay.grid) and np.array_equal(st.pos[b], lay.robots)
        assert tuple(st.target[b]) == tuple(lay.target) and st.heading[b].tolist() == list(lay.headings)
        assert st.cls[b].tolist() == [first, cfg.class_index("explorer")] and st.rng[b] == dyn
        assert st.comm_sigma[b] == (0.0 if sigma is None else sigma) and w.world_keys[b] == world_key(seed, b)
        drawn.add((first, sigma))
    assert len(drawn) > 1  # the draws differ between episodes
