"""The docs/figures scripts that draw from results: each runs on a small result and writes what it says."""

from __future__ import annotations

import csv
import importlib.util
import json
import subprocess
import sys
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


@pytest.mark.slow
def test_learning_curve_trains_on_a_budget_and_plots(tmp_path):
    """Two iterations of the tiny preset after a warm start (the budget is not what ends it), then the
    plot of its evaluations."""
    run = tmp_path / "tiny-warm"
    script = str(ROOT / "docs" / "figures" / "learning_curve.py")
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"}
    train = [sys.executable, script, "--preset", "tiny", "--minutes", "30", "--threads", "1",
             "--set", "warm_start=nearest", "--set", "warm_start_rounds=1", "--set", "warm_start_steps=2",
             "--set", "iterations=2", "--run-dir", str(run)]  # fmt: skip
    subprocess.run(train, check=True, env=env, cwd=tmp_path, capture_output=True)
    out = tmp_path / "curve"
    subprocess.run([sys.executable, script, "--plot", str(run), "--out", str(out)], check=True, env=env,
                   cwd=tmp_path, capture_output=True)  # fmt: skip
    rows = (out.with_suffix(".csv")).read_text().splitlines()
    assert rows[0].startswith("run,phase,step,minutes,success_rate,success_by_100")
    assert any(",warm start," in r for r in rows) and any(",ppo," in r for r in rows)
    meta = json.loads(out.with_suffix(".json").read_text())
    assert {"nearest", "rrt", "random-rescue", "random-uniform"} <= set(meta["planners"]) and meta[
        "cpu_capability"
    ]
    assert out.with_suffix(".png").stat().st_size > 10_000
    # a fine-tuning run on another world continues the first run's clock, in a row of its own
    tuned = tmp_path / "tiny-comm"
    subprocess.run([*train[:8], "--set", "iterations=1", "--set", f"init_from={json.dumps(str(run))}",
                    "--set", 'env_overrides={"map_size": 12, "team": ["rescuer", "explorer"], '
                    '"horizon_ticks": 60, "comm_sigma_choices": [null, 2]}', "--run-dir", str(tuned)],
                   check=True, env=env, cwd=tmp_path, capture_output=True)  # fmt: skip
    subprocess.run([sys.executable, script, "--plot", str(run), str(tuned), "--out", str(out)], check=True,
                   env=env, cwd=tmp_path, capture_output=True)  # fmt: skip
    rows = list(csv.DictReader(out.with_suffix(".csv").open()))
    end = max(float(r["minutes"]) for r in rows if r["run"] == run.name and r["phase"] == "ppo")
    assert min(float(r["minutes"]) for r in rows if r["run"] == tuned.name) > end
    assert set(json.loads(out.with_suffix(".json").read_text())["planners_by_run"]) == {run.name, tuned.name}
