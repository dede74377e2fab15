"""Every example and the demo run end to end on a tiny budget."""

import importlib.util
import json
import math
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _load(path: Path):
    spec = importlib.util.spec_from_file_location(path.stem, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("extra", [[], ["--no-mask"]])
def test_pettingzoo_quickstart(extra):
    episodes = _load(ROOT / "examples" / "pettingzoo_quickstart.py").main(
        ["--preset", "task1", "--episodes", "1", *extra]
    )
    assert len(episodes) == 1 and episodes[0]["decisions"] > 0
    assert (episodes[0]["invalid"] > 0) == bool(extra)  # masked sampling never picks an invalid goal


def test_demo_writes_results_and_gif(tmp_path):
    from catmip_env import demo

    rows = demo.main(
        ["--preset", "task1", "--episodes", "4", "--planners", "nearest,random", "--out", str(tmp_path)]
    )
    saved = json.loads((tmp_path / "results.json").read_text())
    assert saved == rows and [r["planner"] for r in saved] == ["nearest", "random"]
    assert all(0.0 <= r["success_rate"] <= 1.0 and r["episodes"] == 4 for r in saved)
    assert (tmp_path / "results.csv").read_text().startswith("planner,")
    assert (tmp_path / "episode.gif").stat().st_size > 1000


def test_mappo_torchrl_runs_with_finite_losses():
    history = _load(ROOT / "examples" / "mappo_torchrl.py").main(
        ["--frames", "512", "--worlds", "8", "--events", "32", "--epochs", "2", "--minibatch", "128"]
    )
    assert len(history) == 2  # 512 frames = 2 iterations of 8 worlds x 32 events
    for row in history:
        assert all(math.isfinite(row[k]) for k in ("loss_objective", "loss_critic", "loss_entropy"))
        assert row["episodes"] > 0 and 0.0 <= row["success_rate"] <= 1.0
