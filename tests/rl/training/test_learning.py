"""Learning test: a few minutes of training on a small map clearly beats a random policy."""

import numpy as np
import pytest
import torch

from catmip_env.engines.events import EventEngine, random_valid_actions
from catmip_rl.amat.model import AMAT
from catmip_rl.training.collect import Collector
from catmip_rl.training.presets import make_train_config
from catmip_rl.training.train import evaluate_policy, train


def _random_window_success(cfg) -> float:
    """Uniformly random valid window goals for every robot, on the fixed evaluation maps."""
    eng = EventEngine(cfg.eval_env_config(), cfg.eval.eval_episodes, cfg.eval.eval_seed)
    rng = np.random.default_rng(0)
    eng.reset()
    while not eng.state.done.all():
        eng.step(random_valid_actions(eng.masks, rng))
    return float((eng.state.rescue_tick >= 0).mean())


@pytest.mark.slow
def test_small_preset_learns_to_rescue(tmp_path):
    cfg = make_train_config("small", eval_every=0, checkpoint_every=0)
    floor = _random_window_success(cfg)
    evaluator = Collector(cfg.eval_env_config(), cfg.eval.eval_episodes, cfg.eval.eval_seed)
    torch.manual_seed(cfg.seed)
    untrained = evaluate_policy(AMAT(cfg.amat_config()), evaluator, cfg.eval.eval_seed)["success_rate"]
    model = train(cfg, tmp_path / "run", progress=False)
    trained = evaluate_policy(model, evaluator, cfg.eval.eval_seed)["success_rate"]
    print(f"success on {cfg.eval.eval_episodes} fixed maps: random {floor:.2f}, untrained {untrained:.2f}, "
          f"trained {trained:.2f}")  # fmt: skip
    # measured on this machine: random 0.06, untrained 0.22, trained 0.66 (0.53 after 60 iterations)
    assert trained >= 0.5
    assert trained >= floor + 0.3
    assert trained >= untrained + 0.25
