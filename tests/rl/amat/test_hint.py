"""A cell-goal AMAT that reads a planner's proposals (``AmatConfig.hint``): the proposed cell enters as
one more per-cell input and a logit bonus; a model without a hint starts a run with one as the same
function; collection, PPO, imitation, play and the TorchRL actor give the model the same proposals
(``catmip_env.planners.proposals``)."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from catmip_env.config import make_config
from catmip_env.engines.events import EventEngine
from catmip_env.planners.baselines import make_planner
from catmip_env.planners.proposals import NO_PROPOSAL, Proposals
from catmip_rl.amat.config import AmatConfig
from catmip_rl.amat.model import decision_order
from catmip_rl.amat.onboard.execution import CellGoalExecutor
from catmip_rl.amat.pointer import make_model
from catmip_rl.amat.weights import with_hint
from catmip_rl.store.checkpoint import initial_weights, save_model
from catmip_rl.training.collect import Collector
from catmip_rl.training.imitation import DemoBuffer, imitation_loss
from catmip_rl.training.labelers import PlannerLabeler
from catmip_rl.training.presets import make_train_config
from catmip_rl.training.train import build_run, ppo_iteration
from tests.rl.amat.test_pointer import CFG, engine_midway, observation
from tests.rl.helpers import shaken_model

HINTED = replace(CFG, hint="rrt-relay", cell_mask="reachable")  # RRT sends robots into the unknown
PLAIN = replace(HINTED, hint="")


def _logits(model, eng, hint=None):
    obs = observation(eng)
    if hint is not None:
        obs["hint"] = torch.from_numpy(hint)
    active = torch.from_numpy(eng.active & ~eng.state.done[:, None])
    rep, _ = model.encode(model.embed(obs))
    order = decision_order(active)
    actions = torch.zeros(active.shape, dtype=torch.long)
    with torch.no_grad():
        return model.decode_parallel(rep, actions, order, obs["agent_class"], torch.from_numpy(eng.masks))


def test_a_model_given_a_hint_is_the_same_function_until_trained():
    plain = shaken_model(PLAIN, scale=0.3)
    hinted = make_model(HINTED)
    hinted.load_state_dict(with_hint(plain.state_dict()))
    eng = engine_midway()
    proposals = np.asarray(make_planner("rrt-relay", seed=0).act(eng))
    torch.testing.assert_close(_logits(hinted, eng, proposals), _logits(plain, eng))
    # once its new weights move, the proposed cells' logits move and no other cell's does
    with torch.no_grad():
        hinted.hint_bias.fill_(3.0)
    moved = _logits(hinted, eng, proposals) - _logits(plain, eng)
    b, n = np.nonzero(eng.active & ~eng.state.done[:, None])
    assert len(b) and torch.allclose(moved[b, n, proposals[b, n]], torch.tensor(3.0))
    moved[b, n, proposals[b, n]] = 0.0
    assert moved[b, n].abs().max() < 1e-4


def test_every_input_channel_of_the_proposal_counts_once_trained():
    model = shaken_model(HINTED, scale=0.3)
    eng = engine_midway()
    active = eng.active & ~eng.state.done[:, None]
    proposals = np.asarray(make_planner("rrt-relay", seed=0).act(eng))
    elsewhere = np.where(active, (proposals + 1) % eng.masks.shape[-1], -1)  # the next cell instead
    assert (elsewhere[active] != proposals[active]).any()
    assert not torch.allclose(_logits(model, eng, proposals), _logits(model, eng, elsewhere))


def test_a_model_with_a_hint_refuses_an_observation_without_one():
    eng = engine_midway()
    with pytest.raises(ValueError, match="reads the 'rrt-relay' planner's proposals: its obs needs 'hint'"):
        make_model(HINTED).embed(observation(eng))


def test_the_config_names_a_planner_for_a_cell_goal_model():
    with pytest.raises(ValueError, match="hint must name a planner"):
        AmatConfig(goals="cell", hint="oracle")
    with pytest.raises(ValueError, match="set goals to 'cell'"):
        AmatConfig(hint="rrt")


def test_a_run_with_a_hint_starts_from_a_model_without_one(tmp_path):
    plain = shaken_model(PLAIN, scale=0.3)
    save_model(plain, tmp_path / "plain.pt")
    init = initial_weights(str(tmp_path / "plain.pt"), HINTED)
    assert init["source"]["hint"] == ["", "rrt-relay"]
    model = make_model(HINTED)
    model.load_state_dict(init["model"])
    eng = engine_midway()
    proposals = np.asarray(make_planner("rrt-relay", seed=0).act(eng))
    torch.testing.assert_close(_logits(model, eng, proposals), _logits(plain, eng))
    # the other way round is another model: refused
    save_model(model, tmp_path / "hinted.pt")
    with pytest.raises(ValueError, match="hint 'rrt-relay' there vs '' here"):
        initial_weights(str(tmp_path / "hinted.pt"), PLAIN)


def test_play_gives_the_model_the_planners_proposals():
    """With a large bonus on the proposed cell the model plays the planner's goals: the executor runs the
    planner (seeded 0) on the robots' own views at every decision."""
    model = make_model(HINTED)
    with torch.no_grad():
        model.hint_bias.fill_(1e4)
    executor = CellGoalExecutor(model)
    cfg = make_config("task2", comm_sigma=2.0)
    ours, theirs = (EventEngine(cfg, 4, seed=5, goal_mode="cell") for _ in range(2))
    planner = make_planner("rrt-relay", seed=0)
    ours.reset()
    theirs.reset()
    for _ in range(30):
        active = ours.active & ~ours.state.done[:, None]
        mine, planned = executor.act(ours), np.asarray(planner.act(theirs))
        np.testing.assert_array_equal(mine[active], planned[active])
        ours.step(mine)
        theirs.step(np.where(active, planned, mine))
    assert ours.state.done.sum() == theirs.state.done.sum()


def test_collection_gives_the_proposals_play_gives():
    """One producer, one seeding rule (catmip_env.planners.proposals): the collector's hint is what the
    planner seeded 0 proposes on the same maps, whatever the collector's seed or its labeler."""
    model = shaken_model(HINTED, scale=0.3)
    cfg = make_config("task2", comm_sigma=2.0)
    r = Collector(cfg, 4, seed=3, goal_mode="cell").collect(
        model, 0, deterministic=True, labeler=PlannerLabeler(make_planner("rrt-relay", seed=7))
    )
    on = r.active & r.valid[..., None]
    assert (r.hint[on] >= 0).all() and (r.hint[r.valid[..., None] & ~r.active] == NO_PROPOSAL).all()
    # replay the collected actions on a fresh engine of the same maps beside a fresh Proposals
    eng, proposals = EventEngine(cfg, 4, seed=3, goal_mode="cell"), Proposals("rrt-relay")
    eng.reset(episode_indices=np.arange(4))
    for t in range(r.steps):
        live = r.valid[t][:, None]
        np.testing.assert_array_equal(np.where(live, proposals(eng), -1), np.where(live, r.hint[t], -1))
        eng.step(r.action[t])
    # a model without a hint reads none
    plain = Collector(cfg, 4, seed=3, goal_mode="cell").collect(shaken_model(PLAIN, scale=0.3), 0)
    assert (plain.hint[plain.valid] == NO_PROPOSAL).all()


def test_imitation_and_ppo_read_the_hint(tmp_path):
    model = shaken_model(HINTED, scale=0.3)
    col = Collector(make_config("task2", comm_sigma=2.0), 4, seed=3, goal_mode="cell")
    # a labeler seeded as the proposals are (0) draws what they draw: its labels are the proposals
    r = col.collect(model, 0, labeler=make_planner("rrt-relay", seed=0))
    assert np.array_equal(r.label[r.active & r.valid[..., None]], r.hint[r.active & r.valid[..., None]])
    buf = DemoBuffer(10_000)
    buf.add(r)
    batch = buf.batch(np.arange(min(64, len(buf))), 2, "cpu")
    assert "hint" in batch
    loss, stats = imitation_loss(model, batch)
    loss.backward()
    assert model.hint_bias.grad is not None and model.hint_bias.grad.abs() > 0
    # the agreement with labels that are the proposals rises with the bonus alone
    with torch.no_grad():
        model.hint_bias.fill_(1e4)
        _, sure = imitation_loss(model, batch)
    assert sure["imitation/accuracy"] > stats["imitation/accuracy"] and sure["imitation/accuracy"] > 0.95
    cfg = make_train_config(
        "tiny", amat={"goals": "cell", "embed_dim": 32, "hint": "nearest"}, eval_every=0, checkpoint_every=0
    )
    run = build_run(cfg)
    bias = run.model.hint_bias.detach().clone()
    _, _, rollout = ppo_iteration(run, tmp_path)
    assert rollout.hint is not None and not torch.equal(bias, run.model.hint_bias.detach())


def _actor_plays_as_the_executor(model, events=25, **env):
    """CatmipEnv(proposals=...) carries the proposals and the neighbourhoods: AmatActor, argmax, chooses
    the cells CellGoalExecutor chooses on the same maps, event by event."""
    from tensordict.nn import InteractionType, set_interaction_type

    from catmip_rl.adapters import keys as K
    from catmip_rl.adapters.torchrl_actor import AmatActor
    from catmip_rl.adapters.torchrl_env import CatmipEnv

    env = CatmipEnv("task2", num_worlds=3, seed=4, goal_mode="cell", proposals=model.config.hint, **env)
    executor, eng = CellGoalExecutor(model), EventEngine(env.cfg, 3, seed=4, goal_mode="cell")
    actor = AmatActor(model)
    td = env.reset()
    eng.reset()
    with set_interaction_type(InteractionType.DETERMINISTIC):
        for _ in range(events):
            if eng.state.done.all():
                break
            active = eng.active & ~eng.state.done[:, None]
            ours = actor(td).get(K.ACTION).numpy()
            theirs = executor.act(eng)
            np.testing.assert_array_equal(ours[active], theirs[active])
            assert (td.get(K.HINT).numpy()[active] >= 0).all()
            td = env.step(td)["next"]
            eng.step(theirs)


def test_the_torchrl_actor_plays_a_model_with_a_hint_as_the_executor_does():
    _actor_plays_as_the_executor(shaken_model(HINTED, scale=0.3), comm_sigma=2.0)


def test_the_torchrl_actor_plays_the_shipped_amat_general():
    from catmip_rl.store.checkpoint import load_model

    model = load_model("general")  # reads rrt-relay-coord's proposals and the teammate memory
    _actor_plays_as_the_executor(model, events=15, comm_sigma=2.0, **model.config.env_overrides())


def test_a_model_with_a_hint_trains_with_the_ray_collector_config():
    cfg = make_train_config("tiny", amat={"goals": "cell", "hint": "nearest"}, collector="ray")
    assert cfg.model.amat["hint"] == "nearest"
