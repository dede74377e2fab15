"""AMAT with a centralised critic (``AmatConfig.critic = "state"``, ``amat.critic``): what it reads, that
the policy's weights are drawn as before, that PPO trains it (and only it during the value warm-up),
that runs start from a model without it and resume exactly, and the refusals."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from catmip_env import make_config
from catmip_env.engines.events import EventEngine
from catmip_env.planners.baselines import Nearest
from catmip_rl.amat.config import AmatConfig
from catmip_rl.amat.critic import StateCritic, critic_state
from catmip_rl.amat.pointer import make_model
from catmip_rl.store.checkpoint import save_model
from catmip_rl.training.config import TrainConfig
from catmip_rl.training.presets import make_train_config
from catmip_rl.training.train import build_run, ppo_iteration, train

STATE = {"embed_dim": 32, "critic": "state"}


def _named(model, prefix: str, inside: bool = True) -> dict[str, torch.Tensor]:
    return {n: p.detach().clone() for n, p in model.named_parameters() if n.startswith(prefix) == inside}


def _same(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_the_state_is_the_ground_truth_and_the_robots_that_know_the_target():
    engine = EventEngine(make_config("task2"), 4, seed=3, goal_mode="cell")
    engine.reset()
    planner = Nearest(seed=0)
    known = False
    for _ in range(200):  # until a robot of some live world knows the target
        engine.step(planner.act(engine))
        knows = engine.world.knows_target() & ~engine.state.done[:, None]
        if knows.any():
            known = True
            break
    assert known
    state = critic_state(engine.world)
    truth = engine.world.ground_truth(None)
    c = truth.shape[1]
    assert state.dtype == np.uint8 and np.array_equal(state[:, :c], truth.astype(np.uint8))
    expected = np.zeros_like(state[:, c])
    for b, i in zip(*np.nonzero(engine.world.knows_target())):
        expected[b, engine.state.pos[b, i, 0], engine.state.pos[b, i, 1]] = 1
    assert np.array_equal(state[:, c], expected) and expected.any()


def test_the_critic_scores_selected_robots_as_one_convolution_of_state_and_own_map():
    torch.manual_seed(0)
    critic = StateCritic(num_classes=2)
    state = (torch.rand(3, 7, 20, 20) < 0.3).to(torch.uint8)
    gmap = torch.randint(0, 5, (3, 4, 7, 20, 20), dtype=torch.uint8)
    cls = F.one_hot(torch.randint(0, 2, (3, 4)), 2).float()
    every = critic(state, gmap, cls)  # (3, 4, 1)
    rows = torch.tensor([[True, False, True, False], [False, False, False, True], [True, True, True, True]])
    assert torch.allclose(critic(state, gmap, cls, rows), every[rows], atol=1e-6)
    # the split first convolution equals the plain one over the stacked planes
    world, robot = rows.nonzero(as_tuple=True)
    stacked = torch.cat([state[world].float(), gmap[world, robot].float() * 0.25], 1)
    x = F.relu(critic.conv1(stacked))
    x = F.relu(critic.conv2(F.max_pool2d(x, 2, ceil_mode=True)))
    x = F.adaptive_max_pool2d(x, 4).flatten(1)
    plain = critic.fc2(F.relu(critic.fc1(torch.cat([x, cls[world, robot]], -1))))
    assert torch.allclose(critic(state, gmap, cls, rows), plain, atol=1e-5)


@pytest.mark.parametrize("goals", ["window", "cell"])
def test_the_policy_is_drawn_as_without_the_critic(goals):
    amat = {"embed_dim": 16, "goals": goals, "cell_channels": 8, "cell_layers": 2}
    torch.manual_seed(7)
    plain = make_model(AmatConfig(**amat))
    torch.manual_seed(7)
    with_critic = make_model(AmatConfig(**amat, critic="state"))
    assert plain.state_critic is None and with_critic.state_critic is not None
    assert _same(_named(plain, ""), _named(with_critic, "state_critic.", inside=False))
    with pytest.raises(ValueError, match="critic must be one of"):
        AmatConfig(critic="world")


def test_ppo_trains_the_state_critic_alone_in_the_warm_up_then_the_policy_and_never_the_value_head(tmp_path):
    run = build_run(make_train_config("tiny", amat=STATE, value_warmup_iterations=1, eval_every=0))
    critic0, rest0 = _named(run.model, "state_critic."), _named(run.model, "state_critic.", inside=False)
    head0 = _named(run.model, "value_head.")
    _, _, rollout = ppo_iteration(run, tmp_path)
    assert rollout.state is not None and rollout.state.shape[2] == 5 + 2
    assert not _same(critic0, _named(run.model, "state_critic."))  # the warm-up trains the critic
    assert _same(rest0, _named(run.model, "state_critic.", inside=False))  # and nothing else
    row, _, _ = ppo_iteration(run, tmp_path)
    assert not _same(rest0, _named(run.model, "state_critic.", inside=False))  # then the policy too
    assert _same(head0, _named(run.model, "value_head."))  # the encoder's head is not PPO's critic
    assert np.isfinite(row["loss/value"]) and row["loss/value"] > 0


def test_a_run_with_the_state_critic_starts_from_a_model_without_it_and_resumes_exactly(tmp_path):
    torch.manual_seed(1)
    plain = make_model(AmatConfig(embed_dim=32))
    save_model(plain, tmp_path / "plain.pt")
    cfg = make_train_config("tiny", amat=STATE, init_from=str(tmp_path / "plain.pt"), eval_every=0)
    run = build_run(cfg)
    assert run.init_source["critic"] == ["encoder", "state"]
    assert _same(_named(plain, ""), _named(run.model, "state_critic.", inside=False))
    straight = train(cfg, tmp_path / "a", progress=False)
    train(cfg.replace(iterations=1), tmp_path / "b", progress=False)
    resumed = train(cfg, tmp_path / "b", resume=True, progress=False)
    assert _same(_named(straight, ""), _named(resumed, ""))
    # and back: a model with the critic starts a run without it (the critic is left out)
    save_model(straight, tmp_path / "with.pt")
    back = build_run(make_train_config("tiny", amat={"embed_dim": 32}, init_from=str(tmp_path / "with.pt")))
    assert back.model.state_critic is None and back.init_source["critic"] == ["state", "encoder"]


def test_the_state_critic_is_refused_where_it_cannot_be_collected():
    with pytest.raises(ValueError, match="critic 'state' is PPO's: set no warm_start"):
        make_train_config("tiny", amat=STATE, warm_start="nearest")
    with pytest.raises(ValueError, match="critic 'state' needs collector 'local'"):
        make_train_config("tiny", amat=STATE, collector="ray")
    from catmip_rl.adapters.torchrl_actor import AmatCritic

    with pytest.raises(ValueError, match="AmatCritic needs a model with critic 'encoder'"):
        AmatCritic(make_model(AmatConfig(**STATE)))


def test_the_critic_learns_at_its_own_rate_and_the_schedule_keeps_the_ratio(tmp_path):
    from catmip_rl.training.ppo import critic_prefix, make_optimizer

    cfg = make_train_config("tiny", amat=STATE, lr=1e-4, critic_lr=1e-3, iterations=4, eval_every=0)
    run = build_run(cfg)
    policy, critic = run.opt.param_groups
    names = {id(p): n for n, p in run.model.named_parameters()}
    assert all(names[id(p)].startswith("state_critic.") for p in critic["params"]) and critic["critic"]
    assert len(policy["params"]) + len(critic["params"]) == len(list(run.model.parameters()))
    ppo_iteration(run, tmp_path)
    ppo_iteration(run, tmp_path)  # the second of four iterations: the LR at 3/4 of each base
    assert policy["lr"] == pytest.approx(0.75e-4) and critic["lr"] == pytest.approx(0.75e-3)
    plain = make_model(AmatConfig(embed_dim=32))
    assert critic_prefix(plain) == "value_head."
    one_rate = cfg.replace(amat={"embed_dim": 32}, critic_lr=0.0).optim
    assert len(make_optimizer(plain, one_rate).param_groups) == 1
    with pytest.raises(ValueError, match="critic_lr"):
        make_train_config("tiny", critic_lr=-1.0)


def test_the_sigma2_arm_trains_the_state_critic_model_on_the_sigma2_worlds_only():
    # the recorded arm's config (its preset left with its record: docs/notes/retired-presets.json)
    retired = json.loads((Path(__file__).parents[3] / "docs/notes/retired-presets.json").read_text())
    cfg = TrainConfig.from_json(json.dumps(retired["presets"]["general-sigma2"]["config"]))
    worlds = cfg.world_configs()
    assert [(env.map_size, env.slam_noise, n) for env, n in worlds] == [
        (20, 0.0, 128), (20, 0.05, 128), (32, 0.0, 64), (32, 0.05, 64)
    ]  # fmt: skip
    assert all(env.comm_ranges == (2.0,) and env.teammate_memory for env, _ in worlds)
    assert cfg.eval_env_config().comm_sigma == 2.0 and cfg.eval_env_config().map_size == 32
    assert cfg.amat_config().critic == "state" and cfg.loss.anchor == "rrt-relay"
    assert not cfg.imitation.warm_start
