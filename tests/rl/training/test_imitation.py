"""Imitation warm start: labels of the window-projected planner, DAgger's mixture, the cross-entropy
training, and the warm start inside ``train``."""

import csv

import numpy as np
import pytest
import torch

from catmip_env import make_config
from catmip_env.engines.events import EventEngine
from catmip_env.planners.window import make_window_planner
from catmip_rl.amat.config import AmatConfig
from catmip_rl.amat.model import AMAT
from catmip_rl.training.collect import Collector
from catmip_rl.training.imitation import DemoBuffer, dagger, imitation_loss
from catmip_rl.training.labelers import RescueLabeler
from catmip_rl.training.presets import make_train_config
from catmip_rl.training.train import build_run, train


def _labelled(horizon: int, worlds: int, seed: int, teacher_prob: float):
    """(config, collector, rollout) of an untrained AMAT labelled by window:nearest."""
    cfg = make_config("task1", activation=(2, 5), horizon_ticks=horizon)
    col = Collector(cfg, worlds, seed=seed)
    r = col.collect(AMAT(AmatConfig(embed_dim=32)), 0, torch.Generator().manual_seed(0),
                    labeler=make_window_planner("nearest", seed=0), teacher_prob=teacher_prob)  # fmt: skip
    return cfg, col, r


def test_a_pure_teacher_rollout_replays_the_window_planner_and_is_labelled_by_it():
    cfg, col, r = _labelled(horizon=150, worlds=6, seed=4, teacher_prob=1.0)
    act = r.active & r.valid[..., None]
    assert np.array_equal(r.action[act], r.label[act])  # every active robot executed its label
    eng = EventEngine(cfg, 6, seed=4)
    teacher = make_window_planner("nearest", seed=0)
    eng.reset(episode_indices=np.arange(6))
    while not eng.state.done.all():
        eng.step(teacher.act(eng))
    assert np.array_equal(eng.state.rescue_tick, col.engine.state.rescue_tick)
    assert (eng.state.rescue_tick >= 0).mean() >= 0.8


def test_without_the_teacher_the_policy_acts_and_is_still_labelled():
    _, _, r = _labelled(horizon=60, worlds=4, seed=0, teacher_prob=0.0)
    act = r.active & r.valid[..., None]
    assert r.label is not None and (r.action[act] != r.label[act]).any()
    allowed = np.take_along_axis(r.action_mask, r.label[..., None], -1)[..., 0]
    assert allowed[act].all()  # labels are valid window actions


def test_buffer_keeps_the_newest_events():
    cfg = make_config("task1", horizon_ticks=40)
    col = Collector(cfg, 2, seed=0)
    model = AMAT(AmatConfig(embed_dim=32))
    labeler = make_window_planner("nearest")
    buf = DemoBuffer(max_events=50)
    r1 = col.collect(model, 0, labeler=labeler)
    buf.add(r1)
    n1 = int(r1.valid.sum())
    r2 = col.collect(model, 2, labeler=labeler)
    buf.add(r2)
    assert len(buf) == min(50, n1 + int(r2.valid.sum()))
    assert np.array_equal(buf.arrays["global_map"][-1], r2.global_map[r2.valid][-1])


@pytest.mark.slow
def test_dagger_fits_the_teacher():
    cfg = make_config("task1", activation=(2, 5), horizon_ticks=100)
    col = Collector(cfg, 8, seed=0)
    torch.manual_seed(0)
    model = AMAT(AmatConfig(embed_dim=32))
    episodes, log = dagger(model, col, "nearest", rounds=3, steps_per_round=40, batch_events=64, seed=0)
    assert episodes == 24 and [row["round"] for row in log] == [1, 2, 3]
    assert [row["beta"] for row in log] == [1.0, 0.5, 0.25]
    assert log[-1]["imitation/accuracy"] > log[0]["imitation/accuracy"] + 0.15
    assert log[-1]["imitation/loss"] < log[0]["imitation/loss"]
    # on fresh events of the teacher's own episodes the trained model agrees with it far more than chance
    # (the teacher's states, not the model's argmax rollouts: whether those loop depends on float rounding,
    # i.e. on the CPU and torch's thread count, and swings this check from 2.6x to 7x chance)
    r = Collector(cfg, 8, seed=9).collect(
        model, 0, torch.Generator().manual_seed(0), deterministic=True,
        labeler=make_window_planner("nearest"), teacher_prob=1.0,
    )  # fmt: skip
    buf = DemoBuffer(10_000)
    buf.add(r)
    with torch.no_grad():
        _, stats = imitation_loss(model, buf.batch(np.arange(len(buf)), 2, torch.device("cpu")))
    act = buf.arrays["active"]
    chance = float((1.0 / buf.arrays["action_mask"][act].sum(-1)).mean())  # uniform over valid goals
    assert stats["imitation/accuracy"] > 4 * chance


def test_stay_labels_can_be_left_unscored():
    """The teacher says "stay" where its planner has no goal; with warm_start_stay=False those decisions
    leave the loss (the others score as before) and a batch of stays alone gives a zero loss."""
    _, _, r = _labelled(horizon=150, worlds=6, seed=4, teacher_prob=1.0)
    buf = DemoBuffer(10_000)
    buf.add(r)
    stay = AmatConfig().num_actions // 2
    labels, active = buf.arrays["label"], buf.arrays["active"]
    assert (labels[active] == stay).any() and (labels[active] != stay).any()
    torch.manual_seed(0)
    model = AMAT(AmatConfig(embed_dim=32))
    every = buf.batch(np.arange(len(buf)), 2, torch.device("cpu"))
    moving = dict(every, active=every["active"] & (every["label"] != stay))
    with torch.no_grad():
        skipped, _ = imitation_loss(model, every, skip_label=stay)
        expected, _ = imitation_loss(model, moving)
        full, _ = imitation_loss(model, every)
    assert torch.allclose(skipped, expected) and not torch.allclose(skipped, full)
    only_stays = dict(every, label=torch.full_like(every["label"], stay))
    zero, stats = imitation_loss(model, only_stays, skip_label=stay)
    assert float(zero.detach()) == 0.0 and stats["imitation/accuracy"] == 0.0
    zero.backward()  # a step on it changes nothing


def test_the_heading_free_teacher_labels_the_warm_start(tmp_path, monkeypatch):
    import catmip_rl.training.labelers as labelers

    made = []

    def recording(name, seed=0, follow_heading=True):
        made.append((name, follow_heading))
        return make_window_planner(name, seed=seed, follow_heading=follow_heading)

    monkeypatch.setattr(labelers, "make_window_planner", recording)
    for follow in (True, False):
        cfg = make_train_config("tiny", warm_start="rrt", warm_start_heading=follow, warm_start_rounds=1,
                                warm_start_steps=1, iterations=1, eval_every=0)  # fmt: skip
        train(cfg, tmp_path / f"run{follow}", progress=False)
        assert made.pop() == ("rrt", follow)


@pytest.mark.slow
def test_train_warm_starts_once_then_runs_ppo(tmp_path):
    cfg = make_train_config("tiny", warm_start="nearest", warm_start_rounds=2, warm_start_steps=3,
                            value_warmup_iterations=1, iterations=2, eval_every=1)  # fmt: skip
    train(cfg, tmp_path / "run", progress=False)
    rounds = list(csv.DictReader((tmp_path / "run" / "warm_start.csv").open()))
    assert [int(r["round"]) for r in rounds] == [1, 2] and rounds[-1]["eval/success_rate"] != ""
    assert (tmp_path / "run" / "checkpoints" / "iter_000000.pt").exists()
    saved = torch.load(tmp_path / "run" / "checkpoints" / "latest.pt", weights_only=False)
    assert saved["iteration"] == 2 and saved["episodes"] == 4 * cfg.collection.num_worlds
    rows = list(csv.DictReader((tmp_path / "run" / "metrics.csv").open()))
    assert float(rows[0]["time/elapsed_min"]) > float(rounds[-1]["time/elapsed_min"])
    # resuming does not imitate again, not even from the checkpoint written right after the warm start
    train(cfg.replace(iterations=3), tmp_path / "run", resume=True, progress=False)
    assert len(list(csv.DictReader((tmp_path / "run" / "warm_start.csv").open()))) == 2
    ckpts = tmp_path / "run" / "checkpoints"
    (ckpts / "latest.pt").write_bytes((ckpts / "iter_000000.pt").read_bytes())
    before = (tmp_path / "run" / "warm_start.csv").read_text()
    train(cfg, tmp_path / "run", resume=True, progress=False)
    assert (tmp_path / "run" / "warm_start.csv").read_text() == before
    rows = list(csv.DictReader((tmp_path / "run" / "metrics.csv").open()))
    assert [int(r["iteration"]) for r in rows] == [1, 2]


def test_a_warm_start_can_collect_more_episodes_a_round_than_ppo(tmp_path, monkeypatch):
    import catmip_rl.training.imitation as imitation

    seen = []
    real = imitation.dagger

    def recording(model, collector, *args, **kwargs):
        seen.append([c.engine.num_worlds for c in collector])
        return real(model, collector, *args, **kwargs)

    monkeypatch.setattr(imitation, "dagger", recording)
    cfg = make_train_config("tiny", warm_start="nearest", warm_start_rounds=2, warm_start_steps=2,
                            warm_start_worlds=12, iterations=1, eval_every=0)  # fmt: skip
    train(cfg, tmp_path / "run", progress=False)
    rounds = list(csv.DictReader((tmp_path / "run" / "warm_start.csv").open()))
    assert seen == [[12]] and [int(r["episodes"]) for r in rounds] == [12, 24]
    saved = torch.load(tmp_path / "run" / "checkpoints" / "latest.pt", weights_only=False)
    assert saved["episodes"] == 24 + cfg.collection.num_worlds  # PPO's maps follow the warm start's
    with pytest.raises(ValueError, match="warm_start_worlds must be an int >= 0"):
        make_train_config("tiny", warm_start_worlds=-1)


@pytest.mark.parametrize("follow_heading", [True, False])
def test_rescue_labeler_labels_only_rescuers_that_know_the_target_with_the_rescue_rule(follow_heading):
    cfg = make_config("task2", comm_sigma=2.0)  # rescuer, explorer and a third robot; partial news
    eng = EventEngine(cfg, 8, seed=3)
    eng.reset(episode_indices=np.arange(8))
    labeler = RescueLabeler(make_window_planner("nearest", follow_heading=follow_heading))
    teacher = make_window_planner("nearest", follow_heading=follow_heading)
    labelled = unlabelled_rescuers = 0
    while not eng.state.done.all():
        st = eng.state
        label, ref = labeler.act(eng), teacher.act(eng)
        b, n = np.arange(8)[:, None], np.arange(cfg.num_robots)[None, :]
        knows = (st.belief[b, n, st.target[:, None, 0], st.target[:, None, 1]] & 8) != 0
        should = eng.active & ~st.done[:, None] & st.can_rescue & knows
        assert np.array_equal(label[should], ref[should])  # the rescue rule, projected as the teacher does
        assert (label[~should] == -1).all()
        assert (np.take_along_axis(eng.masks, np.maximum(label, 0)[..., None], -1)[..., 0][should] != 0).all()
        labelled += int(should.sum())
        unlabelled_rescuers += int((eng.active & st.can_rescue & ~knows & ~st.done[:, None]).sum())
        eng.step(ref)
    assert labelled > 0 and unlabelled_rescuers > 0  # both cases were met


def test_train_with_the_rescue_loss_logs_it_and_it_pulls_toward_the_rescue_rule(tmp_path):
    cfg = make_train_config("tiny", rescue_coef=1.0, iterations=2, eval_every=0)
    train(cfg, tmp_path / "run", progress=False)
    rows = list(csv.DictReader((tmp_path / "run" / "metrics.csv").open()))
    assert any(float(r["loss/rescue"]) > 0 for r in rows)
    plain = make_train_config("tiny", iterations=1, eval_every=0)
    train(plain, tmp_path / "plain", progress=False)
    assert float(next(csv.DictReader((tmp_path / "plain" / "metrics.csv").open()))["loss/rescue"]) == 0.0
    with pytest.raises(ValueError, match="rescue_coef"):
        make_train_config("tiny", rescue_coef=-0.1)
    with pytest.raises(ValueError, match="rescue_coef > 0 and anchor need collector 'local'"):
        make_train_config("tiny", rescue_coef=0.5, collector="ray", ray_workers=1)


@pytest.mark.parametrize("follow_heading", [True, False])
def test_the_rescue_losss_label_follows_the_heading_as_configured(follow_heading):
    cfg = make_train_config("tiny", rescue_coef=0.3, rescue_heading=follow_heading, eval_every=0)
    run = build_run(cfg)
    assert run.labeler.teacher.follow_heading is follow_heading
    with pytest.raises(ValueError, match="rescue_heading must be true or false"):
        make_train_config("tiny", rescue_heading=0)


@pytest.mark.slow
def test_dagger_of_a_planner_in_its_own_action_space_fits_a_cell_goal_model():
    """A cell-goal model imitates the planner itself (no projection): its labels are cell actions, and
    a few rounds take its agreement with Nearest far above chance on the teacher's own fresh episodes."""
    from catmip_env.planners.baselines import make_planner
    from catmip_rl.amat.pointer import make_model

    cfg = make_config("task1", activation=(2, 5), horizon_ticks=100)
    col = Collector(cfg, 8, seed=0, goal_mode="cell")
    torch.manual_seed(0)
    model = make_model(AmatConfig(goals="cell", embed_dim=32, cell_channels=16, cell_layers=3))
    _, log = dagger(model, col, "nearest", rounds=3, steps_per_round=40, batch_events=64, seed=0)
    assert log[-1]["imitation/accuracy"] > log[0]["imitation/accuracy"]
    r = Collector(cfg, 8, seed=9, goal_mode="cell").collect(
        model, 0, torch.Generator().manual_seed(0), labeler=make_planner("nearest"), teacher_prob=1.0
    )
    act = r.active & r.valid[..., None]
    assert np.take_along_axis(r.action_mask, r.label[..., None], -1)[..., 0][act].all()  # cell labels
    buf = DemoBuffer(10_000)
    buf.add(r)
    with torch.no_grad():
        _, stats = imitation_loss(model, buf.batch(np.arange(len(buf)), 2, torch.device("cpu")))
    chance = float((1.0 / buf.arrays["action_mask"][buf.arrays["active"]].sum(-1)).mean())
    assert stats["imitation/accuracy"] > 10 * chance


def test_labels_the_model_rules_out_are_left_unscored():
    """The cell-goal model narrows the env's mask to known free cells: a label on an unexplored cell
    leaves the loss (a finite loss from the other labels), and a batch of such labels alone scores 0."""
    from catmip_env.planners.baselines import make_planner
    from catmip_rl.amat.pointer import make_model

    cfg = make_config("task1", activation=(2, 5), horizon_ticks=60)
    r = Collector(cfg, 4, seed=0, goal_mode="cell").collect(
        make_model(AmatConfig(goals="cell", embed_dim=32, cell_channels=8)),
        0,
        labeler=make_planner("nearest"),
    )
    buf = DemoBuffer(10_000)
    buf.add(r)
    model = make_model(AmatConfig(goals="cell", embed_dim=32, cell_channels=8))
    batch = buf.batch(np.arange(len(buf)), 2, torch.device("cpu"))
    loss, stats = imitation_loss(model, batch)
    assert torch.isfinite(loss) and stats["imitation/loss"] > 0 and stats["imitation/outside_mask"] < 0.5
    explored = batch["global_map"][:, :, 0] > 0  # (M, N, H, W)
    unexplored = (~explored).flatten(2).float().argmax(-1)  # an unexplored cell of each robot's map
    outside = dict(batch, label=unexplored)
    loss, stats = imitation_loss(model, outside)
    assert loss.item() == 0.0
    assert stats["imitation/accuracy"] == 0.0 and stats["imitation/outside_mask"] == 1.0


@pytest.mark.slow
def test_a_warm_start_with_the_value_head_learns_the_returns_beside_the_labels():
    """With value_norm, DAgger regresses the value head on each finished decision's discounted return
    (async GAE with zero values, lambda 1) and sets the normaliser by them: the critic PPO starts with."""
    from catmip_rl.training.gae import ValueNorm

    cfg = make_config("task1", activation=(2, 5), horizon_ticks=100)
    col = Collector(cfg, 8, seed=0, gamma=0.99)
    torch.manual_seed(0)
    model = AMAT(AmatConfig(embed_dim=32))
    norm = ValueNorm()
    _, log = dagger(model, col, "nearest", rounds=3, steps_per_round=60, batch_events=64, seed=0,
                    value_norm=norm, gamma=0.99)  # fmt: skip
    assert float(norm.debias) > 0
    assert log[-1]["imitation/value_loss"] < 0.8 * log[0]["imitation/value_loss"]
    r = Collector(cfg, 4, seed=9, gamma=0.99).collect(model, 0, labeler=make_window_planner("nearest"))
    buf = DemoBuffer(10_000)
    returns = buf.add(r, gamma=0.99)
    fit = buf.arrays["value_trainable"]
    assert len(returns) == fit.sum() > 0 and np.allclose(buf.arrays["value_target"][fit], returns)
    assert (returns > 0).any()  # the rescue's reward reaches the decisions before it


def _relay_rollout(worlds: int, teacher: str):
    """A Task-1 rollout (sigma = 2: the news travels by relay) played and labelled by ``teacher``."""
    from catmip_env.planners.baselines import make_planner
    from catmip_rl.amat.pointer import make_model

    cfg = make_config("task1", activation=(2, 5), horizon_ticks=100, comm_sigma=2.0)
    model = make_model(AmatConfig(goals="cell", embed_dim=32, cell_channels=8))
    col = Collector(cfg, worlds, seed=0, goal_mode="cell")
    return col.collect(model, 0, labeler=make_planner(teacher, seed=0), teacher_prob=1.0)


def test_a_relay_teachers_relay_labels_are_recorded_and_buffered():
    """A relay planner's labels say which its relay rule chose (active robots only); the buffer keeps
    them, and a relay batch scores those labels alone. Another teacher records none."""
    from catmip_rl.training.imitation import _relay_batch

    r = _relay_rollout(16, "rrt-relay")
    assert r.label_relay is not None and r.label_relay.any()
    assert not (r.label_relay & ~r.active).any()
    buf = DemoBuffer(10_000)
    buf.add(r)
    assert buf.arrays["relay"].sum() == r.label_relay[r.valid].sum()
    events = buf.relay_events
    assert len(events) == buf.arrays["relay"].any(1).sum() > 0
    batch = _relay_batch(buf, np.random.default_rng(0), 32, 2, torch.device("cpu"))
    assert torch.equal(batch["active"], batch["relay"]) and batch["active"].any(1).all()
    plain = DemoBuffer(10_000)
    plain.add(_relay_rollout(4, "nearest"))
    assert not plain.arrays["relay"].any() and len(plain.relay_events) == 0
    assert _relay_batch(plain, np.random.default_rng(0), 32, 2, torch.device("cpu")) is None


@pytest.mark.slow
def test_dagger_with_relay_weight_fits_the_relay_labels_and_refuses_another_teacher():
    """relay_weight adds the relay labels' cross-entropy, logged per round: from the same start and the
    same teacher episodes, the student agrees with more of those labels than one trained without it. A
    teacher without a relay rule is refused."""
    from catmip_env.planners.baselines import make_planner
    from catmip_rl.amat.pointer import make_model
    from catmip_rl.training.imitation import _relay_batch

    cfg = make_config("task1", activation=(2, 5), horizon_ticks=100, comm_sigma=2.0)
    col = Collector(cfg, 16, seed=0, goal_mode="cell")
    agreement = {}
    for weight in (0.0, 2.0):
        torch.manual_seed(0)
        model = make_model(AmatConfig(goals="cell", embed_dim=32, cell_channels=16, cell_layers=3))
        _, log = dagger(model, col, "rrt-relay", rounds=1, steps_per_round=80, batch_events=64, seed=0,
                        relay_weight=weight)  # fmt: skip
        assert ("imitation/relay_loss" in log[0]) == (weight > 0)
        buf = DemoBuffer(10_000)  # the same teacher episodes again (teacher_prob 1: the model does not act)
        buf.add(col.collect(model, 0, labeler=make_planner("rrt-relay", seed=0), teacher_prob=1.0))
        relay = _relay_batch(buf, np.random.default_rng(0), 256, 2, torch.device("cpu"))
        with torch.no_grad():
            agreement[weight] = imitation_loss(model, relay)[1]["imitation/accuracy"]
    assert np.isfinite(log[0]["imitation/relay_loss"])
    assert agreement[2.0] > agreement[0.0] + 0.1
    with pytest.raises(ValueError, match="relay_weight needs a relay planner"):
        dagger(model, col, "nearest", rounds=1, steps_per_round=1, relay_weight=1.0)


def test_the_relay_weight_needs_a_relay_teacher_and_cell_goals():
    base = make_train_config("general-rrt")
    with pytest.raises(ValueError, match="warm_start_relay > 0 weighs a relay teacher"):
        base.replace(warm_start_relay=1.0)  # warm_start "rrt": no relay rule
    assert base.replace(warm_start="rrt-relay", warm_start_relay=1.0).imitation.warm_start_relay == 1.0
    with pytest.raises(ValueError, match="warm_start_relay"):
        base.replace(warm_start="rrt-relay", warm_start_relay=-1.0)
