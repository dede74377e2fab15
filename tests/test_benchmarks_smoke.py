"""benchmarks/run_all.py: the summary judges targets from the measured values; a tiny real run works."""

from __future__ import annotations

import importlib.util
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "benchmarks"


@pytest.fixture(scope="module")
def run_all():
    sys.path.insert(0, str(BENCH))  # run_all imports its sibling ``common``
    try:
        spec = importlib.util.spec_from_file_location("run_all", BENCH / "run_all.py")
        mod = importlib.util.module_from_spec(spec)
        sys.modules["run_all"] = mod  # dataclasses look their module up
        spec.loader.exec_module(mod)
        yield mod
    finally:
        sys.modules.pop("run_all", None)
        sys.path.remove(str(BENCH))


def _engine(task2: float, task3: float, pz: float) -> dict:
    row = {"num_worlds": 64, "overrides": {}}
    return {
        "engine": [{**row, "preset": "task2", "world_ticks_per_s": task2},
                   {**row, "preset": "task3", "world_ticks_per_s": task3}],
        "pettingzoo": [{"preset": "task3", "overrides": {}, "ticks_per_s": pz}],
    }  # fmt: skip


def _write(out: Path, **results: dict) -> None:
    for name, data in results.items():
        (out / f"{name}.json").write_text(json.dumps(data))


def _status(out: Path) -> dict[str, str]:
    return {c["label"]: c["status"] for c in json.loads((out / "run_all.json").read_text())["checks"]}


def test_summary_marks_targets_from_values(run_all, tmp_path):
    _write(
        tmp_path,
        engine=_engine(task2=99_999.0, task3=40_000.0, pz=12_000.0),
        amat={"latency": [{"robots": 6, "map": 32, "active": 6, "decision_ms": 9, "fast_decision_ms": 1.4}]},
        train={"runs": [{"epochs": 2, "num_worlds": 64, "precision": "fp32", "collect_s": 2.5,
                         "advantage_s": 0.1, "update_s": 3.0, "iteration_s": 5.6, "events_per_s": 1_200.0,
                         "world_ticks_per_s": 5_000.0}]},
    )  # fmt: skip
    md, png = run_all.write_summary(tmp_path)
    status = _status(tmp_path)
    assert status["task2, B = 64, full comm"] == "**unmet**"  # just below 100,000
    assert status["task3, B = 64, full comm"] == "met"  # exactly on the target
    assert status["PettingZoo adapter, slowest setting (task3, full comm)"] == "met"
    assert status["batch-1 decision (FastAmat), N = 6, S = 32, all active"] == "met"  # 1.4 <= 1.5 ms
    assert status["collection of 64 episodes"] == "**unmet**"  # 2.5 s > 2 s
    assert status["env-steps/s end to end, 2 epochs"] == "met"
    # no 10-epoch run: estimated as collect + advantages + 5 x update = 17.6 s > 15 s
    est = next(
        c for c in json.loads((tmp_path / "run_all.json").read_text())["checks"] if "est." in c["label"]
    )
    assert est["value"] == pytest.approx(17.6) and est["status"] == "**unmet**"
    text = md.read_text()
    assert "Not run (no JSON)" in text  # events and scaling are missing
    assert "| 99,999 world-ticks/s | ≥ 100,000 world-ticks/s | **unmet** |" in text
    assert png is not None and png.stat().st_size > 10_000


def test_summary_reports_failures_and_ignores_their_stale_json(run_all, tmp_path):
    _write(tmp_path, engine=_engine(task2=1e6, task3=1e6, pz=1e6))
    failed = run_all.RunStatus("engine", ran=True, ok=False, returncode=1, command="python x",
                               error="exit code 1\nTraceback: boom")  # fmt: skip
    md, _ = run_all.write_summary(tmp_path, {"engine": failed})
    text = md.read_text()
    assert "**FAILED**" in text and "Traceback: boom" in text
    assert "1,000,000" not in text  # the stale JSON is not read: its targets count as not measured
    assert set(_status(tmp_path).values()) == {"not measured"} and len(_status(tmp_path)) == 3


def test_paper_targets_not_judged_on_other_world_counts(run_all, tmp_path):
    _write(tmp_path, train={"runs": [{"epochs": 10, "num_worlds": 8, "precision": "fp32", "collect_s": 0.5,
                                      "advantage_s": 0.0, "update_s": 1.0, "iteration_s": 1.5}]})  # fmt: skip
    run_all.write_summary(tmp_path)
    status = _status(tmp_path)
    assert status["paper-recipe iteration (10 epochs)"] == "n/a"
    assert status["collection of 64 episodes"] == "n/a"


def test_executor_checks_need_every_action_the_same_and_no_slowdown(run_all, tmp_path):
    row = {"setting": "task2-full", "worlds": 64, "events": 5, "fast_ms": 40.0, "torch_ms": 60.0}
    rows = [
        row | {"torch_over_fast": 1.5, "decisions": 300, "same_actions": 300},
        row | {"setting": "task3-full", "torch_over_fast": 0.9, "decisions": 200, "same_actions": 199},
    ]
    _write(tmp_path, executor={"machine": {}, "results": rows})  # fmt: skip
    run_all.write_summary(tmp_path, {})
    status = _status(tmp_path)
    assert status["eval decisions, torch / FastAmat per event, task2-full, 64 worlds"] == "met"
    assert status["eval decisions, same actions as torch, task2-full, 64 worlds"] == "met"
    assert status["eval decisions, torch / FastAmat per event, task3-full, 64 worlds"] == "**unmet**"
    assert status["eval decisions, same actions as torch, task3-full, 64 worlds"] == "**unmet**"


def test_thread_checks_judge_split_steps_and_say_when_a_step_stays_on_one_thread(run_all, tmp_path):
    def row(engine, worlds, speedup, split=True):
        return {"engine": engine, "task": "task2", "worlds": worlds, "threads": 2, "split": split,
                "seconds_per_step": 1e-3, "speedup": speedup, "same_worlds_as_one_thread": True}  # fmt: skip

    rows = [row("primitive", 256, 1.65), row("primitive", 64, 0.97, split=False), row("event", 64, 1.55),
            row("event", 16, 0.99)]  # fmt: skip
    _write(tmp_path, threads={"machine": {}, "rows": rows})
    md, _ = run_all.write_summary(tmp_path, {})
    status = _status(tmp_path)
    assert status["primitive engine task2, B = 256, 2 threads"] == "met"
    assert status["event engine task2, B = 64, 2 threads"] == "**unmet**"  # the 1.6x bar
    assert status["event engine task2, B = 16, 2 threads"] == "**unmet**"  # never slower from 16 worlds
    assert status["primitive engine task2, B = 64, 2 threads"] == ""  # one thread either way: not judged
    assert "below the split, one thread either way" in md.read_text()


def test_the_peer_check_is_the_ratio_to_pogema_and_not_measured_without_it(run_all, tmp_path):
    row = {
        "env": "search_rescue_v0",
        "setting": "task2",
        "level": "macro",
        "steps_per_s": 7000.0,
        "rounds": [],
    }
    ratios = [{"setting": "task2", "grid": 20, "agents": 3, "ratio": 1.6, "per_round": [1.58, 1.6, 1.62]},
              {"setting": "task3", "grid": 32, "agents": 6, "ratio": 1.4, "per_round": [1.4]}]  # fmt: skip
    _write(tmp_path, peer={"machine": {}, "rows": [row], "ratios": ratios})
    md, _ = run_all.write_summary(tmp_path, {})
    status = _status(tmp_path)
    assert status["PettingZoo primitive env-steps/s, task2 vs POGEMA 20x20, 3 agents"] == "met"
    assert status["PettingZoo primitive env-steps/s, task3 vs POGEMA 32x32, 6 agents"] == "**unmet**"
    assert "1.60x POGEMA" in md.read_text() and "rounds 1.58, 1.60, 1.62" in md.read_text()
    ratios = [r | {"ratio": None, "per_round": []} for r in ratios]
    _write(tmp_path, peer={"machine": {}, "rows": [row], "ratios": ratios})
    run_all.write_summary(tmp_path, {})
    assert set(v for k, v in _status(tmp_path).items() if "POGEMA" in k) == {"not measured"}


@pytest.mark.slow
def test_run_all_runs_every_benchmark(tmp_path):
    """Every benchmark script for real in its smallest setting, one subprocess each: all exit 0, every
    JSON records the CPU, every target is counted, and the summary and both PNGs are written."""
    tiny = ["--seconds", "0.05", "--pass", "scaling=--maps 15 20 --teams 2 3",
            "--pass", "amat=--repeats 3 --train-steps 1 --bf16-steps 1",
            "--pass", "train=--iterations 1 --epochs 2 --worlds 8",
            "--pass", "events=--decisions 10", "--pass", "executor=--events 2",
            "--pass", "threads=--events 5 --worlds 8", "--pass", "peer=--steps 300"]  # fmt: skip
    cmd = [sys.executable, str(BENCH / "run_all.py"), "--quick", "--out-dir", str(tmp_path), *tiny]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    for row in json.loads((tmp_path / "threads.json").read_text())["rows"]:
        assert row["same_worlds_as_one_thread"], row  # the engine on threads steps the same worlds
    for name in ("engine", "events", "amat", "train", "scaling", "executor", "threads", "peer"):
        data = json.loads((tmp_path / f"{name}.json").read_text())
        assert data["machine"]["cpu_capability"] and isinstance(data["machine"]["native_bf16"], bool), name
    for row in json.loads((tmp_path / "executor.json").read_text())["results"]:
        assert row["same_actions"] == row["decisions"] > 0, row  # FastAmat decides as the torch batch
    data = json.loads((tmp_path / "scaling.json").read_text())
    assert [r["map"] for r in data["curves"]["map_size"]] == [15, 20]
    assert [r["robots"] for r in data["curves"]["team_size"]] == [2, 3]
    for row in data["curves"]["map_size"] + data["curves"]["team_size"]:
        assert row["engine_world_ticks_per_s"] > 0 and row["events_per_s"] > 0 and row["amat_ms"] > 0
    summary = (tmp_path / "SUMMARY.md").read_text()
    assert "## Scaling" in summary and "FAILED" not in summary and "Not run" not in summary
    assert re.search(r"Targets: \*\*\d+ met, \d+ unmet, \d+ not measured\*\* of \d+", summary)
    assert "failed:" not in summary
    for png in ("scaling.png", "summary.png"):
        assert (tmp_path / png).stat().st_size > 10_000
    assert not list(tmp_path.glob("*.tmp*"))  # atomic writes leave no temporaries


def test_a_failed_benchmark_keeps_its_targets_in_the_count(run_all, tmp_path):
    failed = run_all.RunStatus(
        "amat", ran=True, ok=False, returncode=1, command="python x", error="exit code 1"
    )
    md, png = run_all.write_summary(tmp_path, {"amat": failed})
    text = md.read_text()
    assert "not measured** of" in text and "**failed: amat**" in text
    assert "Targets not measured: batch-1 decision (FastAmat), N = 6, S = 32, all active" in text
    checks = json.loads((tmp_path / "run_all.json").read_text())["checks"]
    assert any(c["bench"] == "amat" and c["status"] == "not measured" for c in checks)
    assert png is not None and png.stat().st_size > 5_000
