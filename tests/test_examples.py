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


def test_demo_writes_stats_and_gif(tmp_path):
    from catmip_env import demo

    stats = demo.main(["--preset", "task1", "--episodes", "4", "--out", str(tmp_path)])
    saved = json.loads((tmp_path / "stats.json").read_text())
    assert saved == stats and saved["episodes"] == 4
    assert 0.0 <= saved["success_rate"] <= 1.0 and saved["world_ticks"] > 0
    assert (tmp_path / "episode.gif").stat().st_size > 1000
