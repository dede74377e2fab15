"""An AMAT that reads the env's teammate memory (``AmatConfig.teammate_memory``): its training worlds and
its evaluations turn the observation option on, an engine without it is refused, and it starts from the
weights of a model without it (the option holds no weights)."""

import numpy as np
import pytest
import torch

from catmip_env import make_config
from catmip_env.engines.events import EventEngine
from catmip_rl.amat.config import AmatConfig
from catmip_rl.amat.onboard.execution import CellGoalExecutor
from catmip_rl.amat.pointer import make_model
from catmip_rl.evaluation.evaluate import EvalSetting, evaluate
from catmip_rl.store.checkpoint import save_model
from catmip_rl.training.presets import make_train_config

AMAT = {"embed_dim": 16, "goals": "cell", "cell_channels": 8, "cell_layers": 2}


def test_training_worlds_show_remembered_teammates_to_a_model_that_reads_them():
    plain = make_train_config("tiny", amat=AMAT, worlds=[{"preset": "task2"}, {"comm_sigma": 2.0}])
    memory = plain.replace(amat=AMAT | {"teammate_memory": True})
    assert not plain.env_config().teammate_memory
    assert not any(env.teammate_memory for env, _ in plain.world_configs())
    assert memory.env_config().teammate_memory and memory.eval_env_config().teammate_memory
    assert all(env.teammate_memory for env, _ in memory.world_configs())
    with pytest.raises(ValueError, match="teammate_memory"):
        AmatConfig(teammate_memory="yes")


@pytest.mark.slow
def test_evaluation_turns_the_memory_on_for_such_a_model_and_an_engine_without_it_is_refused(tmp_path):
    model = make_model(AmatConfig(**AMAT, teammate_memory=True))
    save_model(model, tmp_path / "m.pt")
    seen = []
    result = evaluate(
        f"amat:{tmp_path / 'm.pt'}", EvalSetting("task2", comm="2"), episodes=2, seed=5, sampled_too=False,
        allow_other_maps=True, engine_hook=lambda eng: seen.append(eng.cfg.teammate_memory),
    )  # fmt: skip
    assert len(result.episodes) == 2 and seen and all(seen)  # the evaluator gave it the option
    engine = EventEngine(make_config("task2", comm_sigma=2.0), 2, seed=5, goal_mode="cell")
    engine.reset()
    with pytest.raises(ValueError, match="trained with teammate_memory.*teammate_memory=False"):
        CellGoalExecutor(model).act(engine)
    plain = make_model(AmatConfig(**AMAT))
    shown = EventEngine(
        make_config("task2", comm_sigma=2.0, teammate_memory=True), 2, seed=5, goal_mode="cell"
    )
    shown.reset()
    with pytest.raises(ValueError, match="trained without teammate_memory"):
        CellGoalExecutor(plain).act(shown)


def test_a_model_without_memory_starts_a_run_that_reads_it(tmp_path):
    from catmip_rl.training.train import build_run

    plain = make_model(AmatConfig(**AMAT))
    save_model(plain, tmp_path / "plain.pt")
    cfg = make_train_config(
        "tiny", amat=AMAT | {"teammate_memory": True}, init_from=str(tmp_path / "plain.pt")
    )
    run = build_run(cfg)
    assert run.model.config.teammate_memory and run.init_source["teammate_memory"] == [False, True]
    ours, theirs = run.model.state_dict(), plain.state_dict()
    assert all(torch.equal(ours[k], theirs[k]) for k in theirs)  # the option holds no weights
    assert np.all([env.teammate_memory for env, _ in cfg.world_configs()])


def test_a_model_that_reads_headings_gets_them_in_training_and_evaluation_and_nowhere_else(tmp_path):
    """``teammate_heading``: the remembered teammates moved along their headings, on top of the memory."""
    from catmip_rl.training.train import build_run

    with pytest.raises(ValueError, match="teammate_heading .* set teammate_memory too"):
        AmatConfig(**AMAT, teammate_heading=True)
    heading = AMAT | {"teammate_memory": True, "teammate_heading": True}
    cfg = make_train_config("tiny", amat=heading, worlds=[{"preset": "task2"}, {"comm_sigma": 2.0}])
    assert all(env.teammate_heading and env.teammate_memory for env, _ in cfg.world_configs())
    assert cfg.eval_env_config().teammate_heading
    memory = make_model(AmatConfig(**AMAT, teammate_memory=True))
    save_model(memory, tmp_path / "memory.pt")
    run = build_run(cfg.replace(worlds=[], init_from=str(tmp_path / "memory.pt")))
    assert run.init_source["teammate_heading"] == [False, True]  # no weights: the memory model starts it
    model = make_model(AmatConfig(**heading))
    save_model(model, tmp_path / "heading.pt")
    seen = []
    evaluate(f"amat:{tmp_path / 'heading.pt'}", EvalSetting("task2", comm="2"), episodes=1, seed=5,
             sampled_too=False, allow_other_maps=True,
             engine_hook=lambda eng: seen.append(eng.cfg.teammate_heading))  # fmt: skip
    assert seen and all(seen)
    engine = EventEngine(
        make_config("task2", comm_sigma=2.0, teammate_memory=True), 2, seed=5, goal_mode="cell"
    )
    engine.reset()
    with pytest.raises(ValueError, match="trained with teammate_heading.*teammate_heading=False"):
        CellGoalExecutor(model).act(engine)
    with pytest.raises(ValueError, match="trained without teammate_heading"):
        shown = EventEngine(engine.cfg.replace(teammate_heading=True), 2, seed=5, goal_mode="cell")
        shown.reset()
        CellGoalExecutor(memory).act(shown)
