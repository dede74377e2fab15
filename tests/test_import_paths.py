"""Import paths users may already use keep working after the package was reorganised."""

from __future__ import annotations

import importlib
import subprocess
import sys
import warnings

import pytest

from catmip_env.compat import ENV_MOVES


def test_top_level_names():
    import catmip_env
    import catmip_rl
    from catmip_env import BatchedEngine, EventEngine, make_planner, search_rescue_v0
    from catmip_rl import AMAT, AmatConfig, load_model, save_model

    assert catmip_rl.AMAT is AMAT and catmip_rl.load_model is load_model and save_model and AmatConfig
    assert catmip_env.BatchedEngine is BatchedEngine and catmip_env.EventEngine is EventEngine
    assert make_planner("nearest").name == "nearest"
    assert callable(search_rescue_v0.parallel_env)


OLD_RL = {
    "catmip_rl.fast_infer": ("catmip_rl.amat.fast", "FastAmat"),
    "catmip_rl.train": ("catmip_rl.training.train", "train"),
    "catmip_rl.config": ("catmip_rl.training.config", "TrainConfig"),
    "catmip_rl.evaluate": ("catmip_rl.evaluation.evaluate", "evaluate"),
    "catmip_rl.distributed": ("catmip_rl.evaluation.execution", "AmatExecutor"),
    "catmip_rl.env": ("catmip_rl.adapters.torchrl_env", "CatmipEnv"),
}
OLD_ENV = {
    "catmip_env.types": ("catmip_env.constants", "OBS_SCALE"),
    "catmip_env.engine": ("catmip_env.world", "BatchedEngine"),
    "catmip_env.planner": ("catmip_env.paths", "bfs_from"),
    "catmip_env.baselines": ("catmip_env.planners", "make_planner"),
}


@pytest.mark.parametrize("old", sorted(OLD_RL | OLD_ENV))
def test_old_module_paths_warn_and_forward(old):
    new, name = (OLD_RL | OLD_ENV)[old]
    sys.modules.pop(old, None)
    with pytest.warns(DeprecationWarning, match=f"{old} moved to {new}"):
        module = importlib.import_module(old)
    assert getattr(module, name) is getattr(importlib.import_module(new), name)
    assert name in dir(module)
    with pytest.raises(AttributeError):
        module.no_such_name  # noqa: B018


def test_env_aliases_cover_every_move():
    assert set(ENV_MOVES) == set(OLD_ENV)


def test_env_package_stays_torch_free():
    code = "import sys, catmip_env, catmip_env.search_rescue_v0; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


# names of an old module whose contents went to several new ones
SPLIT = {
    "catmip_rl.train": {"async_gae": "catmip_rl.training.gae", "SampleBatch": "catmip_rl.training.ppo",
                        "accumulate_gradients": "catmip_rl.training.ppo",
                        "use_bf16": "catmip_rl.training.precision",
                        "resume_checkpoint": "catmip_rl.checkpoint", "check_new_dir": "catmip_rl.files"},
    "catmip_rl.fast_infer": {"RUN_MAX": "catmip_rl.amat.conv_kernels",
                             "conv_weights": "catmip_rl.amat.conv_kernels"},
    "catmip_rl.evaluate": {"DecisionTracker": "catmip_env.decision_stats"},
    "catmip_env.engine": {"perceive": "catmip_env.dynamics", "VIEW_OFFSETS": "catmip_env.sensing"},
    "catmip_rl.amat": {"EncoderBlock": "catmip_rl.amat.layers", "Attention": "catmip_rl.amat.layers"},
}  # fmt: skip


@pytest.mark.parametrize("old", sorted(SPLIT))
def test_names_of_split_modules_come_from_where_they_went(old):
    if old != "catmip_rl.amat":  # a real package now, not an alias
        sys.modules.pop(old, None)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        module = importlib.import_module(old)
    for name, new in SPLIT[old].items():
        assert getattr(module, name) is getattr(importlib.import_module(new), name), name
        assert name in dir(module)
