"""Import paths: the names users start from are at the top of each package, and every other name has one
path, its module's (the module paths of the layout before 0.1.0 are gone, not aliased)."""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest


def test_top_level_names():
    import catmip_env
    import catmip_rl
    from catmip_env import BatchedWorld, EventEngine, make_planner, search_rescue_v0
    from catmip_rl import AMAT, AmatConfig, load_model, save_model

    assert catmip_rl.AMAT is AMAT and catmip_rl.load_model is load_model and save_model and AmatConfig
    assert catmip_env.BatchedWorld is BatchedWorld and catmip_env.EventEngine is EventEngine
    assert make_planner("nearest").name == "nearest"
    assert callable(search_rescue_v0.parallel_env)


# module paths of the layout before the package was grouped; none is importable
OLD = ("catmip_rl.fast_infer", "catmip_rl.train", "catmip_rl.config", "catmip_rl.evaluate", "catmip_rl.env",
       "catmip_rl.distributed", "catmip_env.types", "catmip_env.engine", "catmip_env.planner",
       "catmip_env.baselines", "catmip_env.compat",
       # 2.0: catmip_env's modules grouped in folders by job (CHANGELOG); the flat paths are gone
       "catmip_env.world", "catmip_env.events", "catmip_env.chunks", "catmip_env.episode_stats",
       "catmip_env.map_sets", "catmip_env.search_rescue_v0", "catmip_env.spaces", "catmip_env.render",
       "catmip_env.machine", "catmip_env.numba_cache", "catmip_env.warmup", "catmip_env.files")  # fmt: skip


@pytest.mark.parametrize("old", OLD)
def test_old_module_paths_are_gone(old):
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module(old)
    assert not any(type(f).__module__.startswith("catmip") for f in sys.meta_path)  # no import hooks


def test_env_package_stays_torch_free():
    code = "import sys, catmip_env, catmip_env.envs.search_rescue_v0; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
