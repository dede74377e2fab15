"""The cell-goal AMAT (amat.pointer): its inputs, its two log-prob paths, neighbourhoods, any map size."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from catmip_env.config import make_config
from catmip_env.constants import EXPLORED, OCCUPIED
from catmip_env.engines.events import EventEngine, random_valid_actions
from catmip_env.planners.core import distance_field
from catmip_rl.amat.config import AmatConfig
from catmip_rl.amat.inputs import macro_observation
from catmip_rl.amat.kernels.cell_fields import cell_fields
from catmip_rl.amat.model import AMAT, decision_order
from catmip_rl.amat.onboard.execution import CellGoalExecutor
from catmip_rl.amat.pointer import PointerAMAT, make_model
from catmip_rl.store.checkpoint import load_model, save_model
from catmip_rl.training.collect import Collector
from tests.rl.helpers import shaken_model

CFG = AmatConfig(goals="cell", embed_dim=32, cell_channels=8, cell_layers=3)


def shaken(seed=0):
    """A cell-goal model far from its init (the 'claimed' weights non-zero), so every input matters."""
    return shaken_model(CFG, seed, scale=0.3)


def engine_midway(preset="task3", worlds=6, seed=0, events=12, **overrides):
    """Worlds some events into their episodes (random valid cell goals), so maps hold explored cells."""
    eng = EventEngine(make_config(preset, **overrides), worlds, seed=seed, goal_mode="cell")
    eng.reset()
    rng = np.random.default_rng(seed)
    for _ in range(events):
        eng.step(random_valid_actions(eng.masks, rng))
    return eng


def observation(eng, groups=True):
    st = eng.state
    return macro_observation(
        eng.obs_global, eng.obs_local, st.cls, 2, st.comp.astype(np.int64) if groups else None
    )


def test_cell_fields_are_the_robots_position_and_path_distance_on_its_own_map():
    eng = engine_midway(slam_noise=0.0)
    pos, dist = cell_fields(eng.obs_global)
    st = eng.state
    np.testing.assert_array_equal(pos, st.pos)
    for b in range(eng.num_worlds):
        for i in range(eng.num_robots):
            blocked = (st.belief[b, i] & OCCUPIED) != 0
            blocked[0, :] = blocked[-1, :] = blocked[:, 0] = blocked[:, -1] = True
            blocked[tuple(st.pos[b, i])] = False
            np.testing.assert_array_equal(dist[b, i], distance_field(blocked, *st.pos[b, i]))


def test_window_amat_refuses_a_cell_config_and_make_model_builds_each_kind():
    with pytest.raises(ValueError, match="make_model"):
        AMAT(CFG)
    assert type(make_model(AmatConfig(embed_dim=32))) is AMAT
    assert type(make_model(CFG)) is PointerAMAT
    with pytest.raises(ValueError, match="goals"):
        AmatConfig(goals="anywhere")


@pytest.mark.parametrize("groups", [True, False])
def test_sampled_log_probs_equal_the_teacher_forced_ones(groups):
    """decode_autoregressive (one position at a time) and score (all at once) give the same log-probs,
    with partial communication (several neighbourhoods) and without."""
    eng = engine_midway(comm_sigma=2.0)
    model = shaken()
    obs = observation(eng, groups)
    active = torch.from_numpy(eng.active.copy())
    active[:, ::2] = True  # several deciders per world
    mask = torch.from_numpy(eng.masks.copy())
    order = decision_order(active)
    rep, values = model.encode(model.embed(obs))
    gen = torch.Generator().manual_seed(0)
    actions, logp = model.decode_autoregressive(rep, mask, order, active, obs["agent_class"], generator=gen)
    logits, v_sel = model.score(model.embed(obs), actions, order, obs["agent_class"], active, mask)
    lp = torch.log_softmax(logits, -1).gather(1, actions[active][:, None])[:, 0]
    torch.testing.assert_close(lp, logp[active], atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(v_sel, values[active])
    every = model.decode_parallel(rep, actions, order, obs["agent_class"], mask)  # (B, N, H * W)
    torch.testing.assert_close(every[active], logits)
    assert len(set(eng.state.comp.flatten().tolist())) > 1 or not groups


def test_chosen_goals_are_known_free_reachable_cells_or_stay():
    eng = engine_midway()
    model = shaken(1)
    obs = observation(eng)
    active = torch.from_numpy(eng.active.copy())
    rep, _ = model.encode(model.embed(obs))
    mask = torch.from_numpy(eng.masks.copy())
    actions, _ = model.decode_autoregressive(rep, mask, decision_order(active), active, obs["agent_class"])
    st, w = eng.state, eng.shape[1]
    _, dist = cell_fields(eng.obs_global)
    for b, i in zip(*np.nonzero(eng.active)):
        r, c = divmod(int(actions[b, i]), w)
        assert eng.masks[b, i, r * w + c]
        own = (r, c) == tuple(st.pos[b, i])
        assert own or ((st.belief[b, i, r, c] & EXPLORED) and dist[b, i, r, c] >= 0)


@pytest.mark.parametrize("cell_mask", ["known", "reachable"])
def test_the_mask_is_the_envs_narrowed_to_the_cells_the_config_names(cell_mask):
    """ "known": explored cells with a path on the robot's map (the frontier planners' goals); "reachable":
    unknown cells with a path too (RRT's goals); the robot's own cell always."""
    eng = engine_midway()
    model = make_model(replace(CFG, cell_mask=cell_mask))
    emb = model.embed(observation(eng))
    rows = torch.arange(eng.num_worlds * eng.num_robots)
    _, allowed = model.cell_features(emb.cells, rows)
    allowed = allowed.view(eng.num_worlds, eng.num_robots, *eng.shape).numpy()
    st = eng.state
    _, dist = cell_fields(eng.obs_global)
    explored = (st.belief & EXPLORED) != 0
    expected = (dist >= 0) & (explored if cell_mask == "known" else True)
    b, i = np.indices((eng.num_worlds, eng.num_robots))
    expected[b, i, st.pos[..., 0], st.pos[..., 1]] = True
    np.testing.assert_array_equal(allowed, expected)
    assert (allowed & ~explored).any() == (cell_mask == "reachable")


def test_a_neighbourhood_decides_as_it_would_alone():
    """With the neighbourhood input, a world's robots in two neighbourhoods decide exactly as each
    neighbourhood decides on a batch of its own members (decentralised execution)."""
    eng = engine_midway(worlds=3)
    model = shaken(2)
    st = eng.state
    comp = np.zeros_like(st.comp)
    comp[:, 3:] = 3  # robots 0-2 and 3-5
    active = np.ones_like(eng.active)
    obs = macro_observation(eng.obs_global, eng.obs_local, st.cls, 2, comp)
    act = torch.from_numpy(active)
    mask = torch.from_numpy(eng.masks.copy())
    rep, values = model.encode(model.embed(obs))
    together, _ = model.decode_autoregressive(
        rep, mask, decision_order(act), act, obs["agent_class"], deterministic=True
    )
    for members in (slice(0, 3), slice(3, 6)):
        sub = {k: v[:, members] for k, v in obs.items()}
        rep_s, values_s = model.encode(model.embed(sub))
        alone, _ = model.decode_autoregressive(
            rep_s, mask[:, members], decision_order(act[:, members]), act[:, members], sub["agent_class"],
            deterministic=True,
        )  # fmt: skip
        torch.testing.assert_close(values_s, values[:, members])
        torch.testing.assert_close(alone, together[:, members])


def test_one_model_plays_any_map_size_and_team_and_survives_a_checkpoint(tmp_path):
    model = shaken(3)
    path = save_model(model, tmp_path / "cell.pt")
    loaded = load_model(path)
    assert type(loaded) is PointerAMAT and loaded.config == CFG
    for preset in ("task1", "task3"):
        eng = EventEngine(make_config(preset), 4, seed=1, goal_mode="cell")
        eng.reset(episode_indices=np.arange(4))
        a = CellGoalExecutor(model).act(eng)
        eng2 = EventEngine(make_config(preset), 4, seed=1, goal_mode="cell")
        eng2.reset(episode_indices=np.arange(4))
        np.testing.assert_array_equal(a, CellGoalExecutor(loaded).act(eng2))
        for _ in range(5):  # valid actions: the engine raises on a masked one
            eng.step(CellGoalExecutor(model).act(eng))


def test_a_cell_goal_rollout_trains_with_the_ppo_loss():
    """Collected in cell mode with neighbourhoods, re-scored by the PPO loss: the ratio starts at 1."""
    from catmip_rl.training.gae import ValueNorm, build_batch
    from catmip_rl.training.ppo import ppo_loss

    model = shaken(4)
    col = Collector(make_config("task1", horizon_ticks=40, comm_sigma=2.0), 4, seed=0, goal_mode="cell")
    r = col.collect(model, 0, torch.Generator().manual_seed(0))
    batch, _ = build_batch(r, ValueNorm(), 0.99, 0.95, 2, torch.device("cpu"))
    assert batch.neighbourhood is not None and batch.action_mask.shape[-1] == 15 * 15
    loss, stats = ppo_loss(model, batch)
    assert abs(float(stats["ppo/approx_kl"])) < 1e-5 and float(stats["ppo/clip_fraction"]) == 0.0
    loss.backward()
    assert model.query[0].weight.grad.abs().sum() > 0 and model.cell_in.weight.grad.abs().sum() > 0


def test_the_loop_guard_never_leaves_a_cell_goal_robot_without_a_cell_its_model_allows(monkeypatch):
    """The guard masks a stalled robot's last goal in the engine's mask; where that was the one cell the
    model's own mask left, the robot decides again on its unguarded mask. Here the guard leaves each robot
    only the last cell the engine allows, an unknown corner that the model's mask (known cells) rules out."""
    eng = EventEngine(make_config("task3"), 2, seed=1, goal_mode="cell")
    eng.reset(episode_indices=np.arange(2))
    model = shaken(5)
    guarded = CellGoalExecutor(model, loop_guard=True)
    last = eng.masks.shape[-1] - 1 - np.argmax(eng.masks[..., ::-1], -1)
    robbed = np.zeros_like(eng.masks)
    np.put_along_axis(robbed, last[..., None], 1, -1)
    monkeypatch.setattr(guarded, "_guarded_masks", lambda engine, active: robbed)
    passes = []
    decode = model.decode_autoregressive
    monkeypatch.setattr(model, "decode_autoregressive", lambda *a, **k: passes.append(1) or decode(*a, **k))
    a = guarded.act(eng)
    assert len(passes) == 2  # the corner was lost: a second pass on the unguarded masks
    assert np.take_along_axis(eng.masks, a[..., None], -1).all()  # every robot: a cell the engine allows
    eng.step(a)
