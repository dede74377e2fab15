"""Every example and the demo run end to end on a tiny budget."""

import importlib.util
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _load(path: Path):
    spec = importlib.util.spec_from_file_location(path.stem, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_pettingzoo_quickstart():
    returns = _load(ROOT / "examples" / "pettingzoo_quickstart.py").main(
        ["--preset", "task1", "--episodes", "1"]
    )
    assert len(returns) == 1


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
