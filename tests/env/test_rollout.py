"""The rollout teacher: it never reads the true target, it is deterministic
per seed and batch invariant, it plays full episodes, and with the search off it is rrt-relay-coord."""

import numpy as np
import pytest

from catmip_env import make_config
from catmip_env.constants import CLUE, EXPLORED, FREE, TARGET
from catmip_env.engines.events import EventEngine
from catmip_env.planners import make_planner
from catmip_env.planners.rollout import RolloutPlanner, known_world, load

SMALL = {"candidates": 3, "samples": 2, "horizon": 20}
SIGMA2_NOISE = {"comm_sigma": 2.0, "slam_noise": 0.05}  # the setting of the pilot


def _engine(preset="task2", worlds=3, seed=31000, **overrides):
    return EventEngine(make_config(preset, **(SIGMA2_NOISE | overrides)), worlds, seed=seed, goal_mode="cell")


def _play(planner, eng, episodes=None, max_events=None):
    eng.reset(episode_indices=episodes)
    goals = []
    while not eng.state.done.all() and (max_events is None or len(goals) < max_events):
        a = planner.act(eng)
        goals.append(np.where(eng.active & ~eng.state.done[:, None], a, -1))
        eng.step(a)
    return eng.state.rescue_tick.copy(), goals


def test_with_the_search_off_it_is_rrt_relay_coord():
    ticks_a, goals_a = _play(RolloutPlanner(seed=5, when="off"), _engine())
    ticks_b, goals_b = _play(make_planner("rrt-relay-coord", seed=5), _engine())
    assert (ticks_a == ticks_b).all()
    assert all((a == b).all() for a, b in zip(goals_a, goals_b))


class _Checked(RolloutPlanner):
    """Checks, at every search, that RRT's ranking starts with the base planner's own goal."""

    checked = 0

    def candidate_goals(self, ctx, goal, rrt_state=None):
        if not self.relayed[ctx.b, ctx.i]:
            ranked = self.ranked_clusters(ctx, rrt_state)
            assert ranked and ranked[0] == goal
            self.checked += 1
        return super().candidate_goals(ctx, goal, rrt_state)


def test_the_ranking_of_clusters_is_rrt_relay_coords_and_candidates_are_valid():
    planner = _Checked(seed=1, when="always", **SMALL)
    eng = _engine(worlds=2)
    _play(planner, eng, max_events=12)
    assert planner.checked > 5 and planner.stats["searches"] > 5


def _moved_target(eng: EventEngine, b: int) -> None:
    """Move world b's true target (and its clues) to another cell no robot has seen."""
    st = eng.state
    grid = st.grid[b]
    grid[(grid == TARGET) | (grid == CLUE)] = FREE
    seen = ((st.belief[b] & EXPLORED) != 0).any(axis=0)
    r, c = st.target[b]
    cells = [
        (y, x)
        for y, x in np.argwhere((grid == FREE) & ~seen)
        if 2 <= y < grid.shape[0] - 2
        and 2 <= x < grid.shape[1] - 2
        and abs(y - r) + abs(x - c) > 4
        and not seen[y - 1 : y + 2, x - 1 : x + 2].any()
    ]
    y, x = cells[len(cells) // 2]
    box = grid[y - 1 : y + 2, x - 1 : x + 2]
    box[box == FREE] = CLUE
    grid[y, x] = TARGET
    st.target[b] = (y, x)


def test_the_continuations_never_read_the_true_target():
    """Two engines at the same event, the true target moved in one (unseen by the team): the same goals,
    the same searches; and the team's world (known_world) is the same."""
    a, b = _engine(worlds=3), _engine(worlds=3)
    walker = make_planner("rrt-relay-coord", seed=3)
    for eng in (a, b):
        eng.reset()
    for _ in range(2):  # a few events in
        act = walker.act(a)
        a.step(act)
        b.step(act)
    unseen = np.flatnonzero(~a.world.knows_target().any(axis=1))
    assert len(unseen) >= 2
    for w in unseen:
        _moved_target(b, w)
    assert (a.state.target[unseen] != b.state.target[unseen]).any(axis=1).all()
    for w in unseen:
        for i in range(a.num_robots):
            ka, kb = known_world(a, w, i), known_world(b, w, i)
            assert (ka["grid"] == kb["grid"]).all() and (ka["cells"] == kb["cells"]).all()
    pa, pb = RolloutPlanner(seed=9, when="always", **SMALL), RolloutPlanner(seed=9, when="always", **SMALL)
    assert (pa.act(a) == pb.act(b)).all()
    assert pa.stats["searches"] == pb.stats["searches"] > 0
    assert pa.stats["changed"] == pb.stats["changed"]


def test_a_continuation_reads_only_what_the_deciding_robot_knows():
    """A robot's world is its own belief: what a teammate outside its neighbourhood saw since they last
    talked does not enter it, and that teammate stands where the robot last heard of it."""
    eng = _engine(worlds=4, comm_sigma=1.0)  # links rarely hold: neighbourhoods split early
    eng.reset()
    walker = make_planner("rrt-relay-coord", seed=3)
    for _ in range(12):
        eng.step(walker.act(eng))
    st = eng.state
    b, i, j = next(
        (b, i, j)
        for b in range(4)
        for i in range(eng.num_robots)
        for j in range(eng.num_robots)
        if st.comp[b, i] != st.comp[b, j] and st.heard_tick[b, i, j] >= 0
    )
    world = known_world(eng, b, i)
    seen_by_i = (st.belief[b, i] & EXPLORED) != 0
    assert (world["grid"][1:-1, 1:-1][~seen_by_i[1:-1, 1:-1]] == FREE).all()  # the rest: unknown, free
    sim = EventEngine(eng.cfg, 1, seed=0, goal_mode="cell", invalid_action="stay")
    load(sim, 0, eng, b, i, world, np.random.default_rng(0), 0, 1)
    assert (sim.state.pos[0, j] == st.heard_pos[b, i, j]).all()
    assert (sim.state.belief[0, j] == st.belief[b, i]).all()


def test_deterministic_per_seed_and_batch_invariant():
    knobs = {"when": "both", "late_tick": 30, **SMALL}
    batch, goals_1 = _play(RolloutPlanner(seed=4, **knobs), _engine(worlds=3))
    again, goals_2 = _play(RolloutPlanner(seed=4, **knobs), _engine(worlds=3))
    assert (batch == again).all() and all((x == y).all() for x, y in zip(goals_1, goals_2))
    for k in range(3):  # each map alone: the same episode as in the batch
        alone, _ = _play(RolloutPlanner(seed=4, **knobs), _engine(worlds=1), episodes=[k])
        assert alone[0] == batch[k]


@pytest.mark.parametrize("preset", ["task1", "task2"])
def test_it_plays_full_episodes(preset):
    planner = RolloutPlanner(seed=0, when="always", **SMALL)
    ticks, _ = _play(planner, _engine(preset, worlds=3))
    assert (ticks >= 0).all()
    assert planner.stats["searches"] > 0


def test_it_plays_from_the_engine_view_a_policy_is_given(monkeypatch):
    """Through the read-only view (no true map, the target only where a robot knows it): no withheld
    read, and the same goals as on the engine itself once both key their streams alike (the view keys
    them on the world keys, the engine on seed and episode: ``stream_key``)."""
    user_policy = pytest.importorskip("catmip_rl.evaluation.user_policy")
    import catmip_env.planners.core as core
    import catmip_env.planners.rollout as rollout

    keyed = core.stream_key

    def by_world_key(engine, b):
        world = engine.world
        return (int(world.world_keys[b]),) if hasattr(world, "world_keys") else keyed(engine, b)

    for module in (core, rollout):
        monkeypatch.setattr(module, "stream_key", by_world_key)
    eng = _engine(worlds=2)
    eng.reset()
    on_view = RolloutPlanner(seed=2, when="always", **SMALL)
    on_engine = RolloutPlanner(seed=2, when="always", **SMALL)
    for _ in range(6):
        act = on_view.act(user_policy.engine_view(eng))
        assert (act == on_engine.act(eng)).all()
        eng.step(act)
    assert on_view.stats["searches"] > 0


def test_knobs_are_checked():
    with pytest.raises(ValueError, match="unknown when"):
        RolloutPlanner(when="sometimes")
    with pytest.raises(ValueError, match=">= 1"):
        RolloutPlanner(samples=0)
