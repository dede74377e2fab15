"""The docs/figures scripts that draw from results: each runs on a small result and writes what it says."""

from __future__ import annotations

import csv
import importlib.util
import json
from pathlib import Path

import pytest

from catmip_rl.evaluation.evaluate import EvalSetting, evaluate
from catmip_rl.training.presets import make_train_config
from catmip_rl.training.train import train

ROOT = Path(__file__).resolve().parents[1]


def _script(name: str):
    path = ROOT / "docs" / "figures" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_episode_phases_sorts_every_episode_into_its_last_phase(tmp_path, monkeypatch):
    for method in ("nearest", "random-uniform"):
        evaluate(method, EvalSetting("task1", "2"), episodes=6, seed=0).write(tmp_path / "r" / method)
    phases = _script("episode_phases")
    monkeypatch.setattr("sys.argv", ["episode_phases.py", str(tmp_path / "r"), "--out", str(tmp_path / "ph")])
    phases.main()
    rows = {r["method"]: r for r in csv.DictReader((tmp_path / "ph.csv").open())}
    for method, row in rows.items():
        episodes = json.loads((tmp_path / "r" / method / "episodes.json").read_text())
        lost = sum(not e["rescued"] for e in episodes)
        parts = ("lost_never_found", "lost_nobody_told", "lost_told_not_there")
        assert sum(int(row[k]) for k in parts) == lost
        assert float(row["success_rate"]) == pytest.approx(1 - lost / len(episodes))
    assert "| task1-sigma2-noise0-ma10 | nearest |" in (tmp_path / "ph.md").read_text()
    assert (tmp_path / "ph.png").stat().st_size > 1000


def test_fig5_draws_a_runs_warm_start_and_ppo_points(tmp_path, monkeypatch):
    cfg = make_train_config("tiny", warm_start="nearest", warm_start_rounds=2, warm_start_steps=1,
                            iterations=2, eval_every=1)  # fmt: skip
    train(cfg, tmp_path / "run", progress=False)
    fig5 = _script("fig5")
    monkeypatch.setattr("sys.argv", ["fig5.py", f"A={tmp_path / 'run'}", "--out", str(tmp_path / "f5")])
    fig5.main()
    rows = list(csv.DictReader((tmp_path / "f5.csv").open()))
    assert [(r["phase"], int(r["episodes"])) for r in rows] == [
        ("warm start", 8), ("warm start", 16), ("ppo", 24), ("ppo", 32)
    ]  # fmt: skip
    assert all(r["eval_success"] != "nan" for r in rows)
    assert (tmp_path / "f5.png").stat().st_size > 1000
