"""catmip compare: paired differences with known answers, across-seed statistics, the CLI's files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from catmip_rl.benchmark.compare import compare
from catmip_rl.benchmark.results import load_results
from catmip_rl.cli.main import main
from catmip_rl.evaluation.stats import mcnemar_p, paired_difference


def _write(
    folder: Path, method: str, ticks: list[int | None], label: str = "task1-full-noise0-ma10", maps=None
):
    folder.mkdir(parents=True)
    maps = maps or [f"{e:08x}" for e in range(len(ticks))]
    rows = [{"map_hash": m, "rescue_tick": t} for m, t in zip(maps, ticks)]
    (folder / "episodes.json").write_text(json.dumps(rows))
    summary = {"method": method, "label": label, "horizon": 300, "seed": 0}
    (folder / "summary.json").write_text(json.dumps(summary))


def test_paired_difference_and_mcnemar_known_answers():
    a = np.array([1, 1, 1, 1, 0, 0, 1, 1, 1, 1], bool)
    b = np.array([1, 0, 0, 0, 0, 0, 1, 1, 1, 1], bool)
    d = paired_difference(a, b)
    assert d["diff"] == pytest.approx(0.3) and d["ci_low"] <= 0.3 <= d["ci_high"] and d["ci_low"] >= 0.0
    assert mcnemar_p(a, b) == pytest.approx(0.25)  # 3 discordant maps, all for a: 2 * 0.5**3
    same = paired_difference(a, a)
    assert same == {"diff": 0.0, "ci_low": 0.0, "ci_high": 0.0}


def test_compare_pairs_only_the_same_maps_and_aggregates_runs(tmp_path):
    ticks_a = [50] * 80 + [None] * 20  # 0.8 by tick 100
    ticks_b = [50] * 60 + [150] * 20 + [None] * 20  # 0.6 by tick 100, the same maps
    _write(tmp_path / "a", "a", ticks_a)
    _write(tmp_path / "b", "b", ticks_b)
    for k, rate in enumerate((0.5, 0.6, 0.7)):  # three training seeds of "c"
        n = int(rate * 100)
        _write(tmp_path / f"c{k}", f"c-seed{k}", [40] * n + [None] * (100 - n))
    _write(tmp_path / "other", "a", [10] * 100, maps=[f"{e + 500:08x}" for e in range(100)], label="task2-x")
    seeds = f"c={tmp_path}/c0,{tmp_path}/c1,{tmp_path}/c2"
    results = load_results([str(tmp_path / "a"), str(tmp_path / "b"), seeds, str(tmp_path / "other")])
    with pytest.raises(ValueError, match=r"other \(a: task2-x.* and .*b \(b\) were not played alike"):
        compare(results)  # only "a" played task2-x: refused without unpaired
    report = compare(results, unpaired=True)
    pairs = {(r["method_a"], r["method_b"]): r for r in report.paired}
    ab = pairs[("a", "b")]
    assert ab["diff"] == pytest.approx(0.2) and ab["ci_low"] > 0.1 and ab["ci_high"] < 0.3
    # over the 80 maps both rescued: 60 at 50 vs 50, 20 at 50 vs 150
    assert ab["tick_diff"] == pytest.approx(-25.0) and ab["both_rescued"] == 80
    ac = pairs[("a", "c")]
    assert ac["runs_b"] == 3 and ac["success_b"] == pytest.approx(0.6) and ac["mcnemar_p"] is None
    assert report.settings == ["task1-full-noise0-ma10"] and report.left_out == ["task2-x"]
    cell = {(r["method"], r["setting"]): r for r in report.by_setting}
    c = cell[("c", "task1-full-noise0-ma10")]  # three seeds at 0.5, 0.6, 0.7
    assert (c["runs"], c["ci_over"]) == (3, "runs and maps") and c["success_by_100"] == pytest.approx(0.6)
    assert 0.4 < c["ci_low"] < 0.55 and 0.65 < c["ci_high"] < 0.8  # the seeds' spread and the maps' together
    a = cell[("a", "task1-full-noise0-ma10")]
    assert a["ci_over"] == "maps" and a["ci_low"] < 0.8 < a["ci_high"] and a["success"] == pytest.approx(0.8)
    assert cell[("a", "task2-x")]["success_by_100"] == 1.0  # a setting only "a" played is still listed
    assert not cell[("a", "task2-x")]["paired"] and c["paired"]  # ... marked unpaired
    agg = {r["method"]: r for r in report.aggregate}
    assert agg["c"]["runs"] == 3 and agg["c"]["mean"] == pytest.approx(0.6)
    assert agg["c"]["mean_ci_low"] <= 0.6 <= agg["c"]["mean_ci_high"] and agg["a"]["mean_ci_low"] is None
    poi = {(r["method_x"], r["method_y"]): r["probability"] for r in report.improvement}
    assert (
        poi[("a", "c")] == pytest.approx(1.0) and ("a", "b") not in poi
    )  # one run each: nothing to resample


def test_runs_and_maps_ci_covers_both_sources():
    from catmip_rl.evaluation.stats import runs_and_maps_ci

    rng = np.random.default_rng(0)
    same = np.tile(rng.random(400) < 0.7, (3, 1))  # three identical runs: only the maps vary
    low, high = runs_and_maps_ci(same)
    se = np.sqrt(0.7 * 0.3 / 400)
    assert high - low == pytest.approx(2 * 1.96 * se, rel=0.25)
    spread = np.array([rng.random(400) < p for p in (0.5, 0.7, 0.9)])  # the runs differ as well
    low2, high2 = runs_and_maps_ci(spread)
    assert high2 - low2 > 2 * (high - low)


def test_shared_resamples_give_the_intervals_of_one_at_a_time():
    from catmip_rl.evaluation.stats import runs_and_maps_ci, shared_maps_cis

    rng = np.random.default_rng(1)
    arrays = [rng.random((1, 1000)) < 0.6, np.array([rng.random(1000) < p for p in (0.3, 0.5, 0.6)])]
    arrays.append(arrays[0].astype(float) - arrays[1].mean(axis=0))  # a paired difference
    for shared, alone in zip(shared_maps_cis(arrays), (runs_and_maps_ci(a.astype(float)) for a in arrays)):
        assert shared == pytest.approx(alone, abs=0.01)  # the same scheme, other random draws


def test_cli_compare_writes_tables_and_plots(tmp_path, capsys):
    _write(tmp_path / "r" / "a", "a", [50] * 70 + [None] * 30)
    _write(tmp_path / "r" / "b", "b", [60] * 50 + [None] * 50)
    out = tmp_path / "cmp"
    assert main(["compare", str(tmp_path / "r"), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "| task1-full-noise0-ma10 | a | b | 100 | 0.700 | 0.500 | +0.200 [" in text
    for name in ("paired.csv", "aggregate.csv", "compare.md", "paired.png"):
        assert (out / name).stat().st_size > 0, name
    for name in ("improvement.csv", "aggregate.png", "profile.png"):  # one run each: nothing across seeds
        assert not (out / name).exists(), name
    assert "wrote " in text and "improvement.csv" not in text.splitlines()[-1]
    assert main(["compare", str(tmp_path / "nothing"), "--out", str(tmp_path / "x")]) == 2
    assert "no such result folder" in capsys.readouterr().err
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "summary.json").write_text("{")
    (tmp_path / "bad" / "episodes.json").write_text("[]")
    assert main(["compare", str(tmp_path / "bad"), "--out", str(tmp_path / "y")]) == 2
    assert "is not a readable catmip eval result" in capsys.readouterr().err
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()
    # several runs of a method: the across-run plots are drawn
    _write(tmp_path / "s" / "a2", "a", [50] * 60 + [None] * 40)
    seeds = f"a={tmp_path / 'r' / 'a'},{tmp_path / 's' / 'a2'}"
    assert main(["compare", seeds, str(tmp_path / "r" / "b"), "--out", str(tmp_path / "runs")]) == 0
    for name in ("aggregate.png", "profile.png", "improvement.csv"):
        assert (tmp_path / "runs" / name).stat().st_size > 0, name


def test_vs_and_pairs_choose_the_comparisons_and_one_run_each_draws_no_aggregate_plot(tmp_path, capsys):
    for name, rate in (("a", 0.8), ("b", 0.6), ("ref", 0.5)):
        n = int(rate * 100)
        _write(tmp_path / "r" / name, name, [50] * n + [None] * (100 - n))
    report = compare(load_results([str(tmp_path / "r")]), vs="ref")
    assert [(r["method_a"], r["method_b"]) for r in report.paired] == [("a", "ref"), ("b", "ref")]
    assert report.paired[0]["diff"] == pytest.approx(0.3)  # a - ref
    chosen = compare(load_results([str(tmp_path / "r")]), pairs=[("ref", "b")])
    assert [(r["method_a"], r["method_b"], round(r["diff"], 3)) for r in chosen.paired] == [
        ("ref", "b", -0.1)
    ]
    with pytest.raises(ValueError, match=r"no results of method 'rf'.*\['a', 'b', 'ref'\]"):
        compare(load_results([str(tmp_path / "r")]), vs="rf")
    out = tmp_path / "out"
    assert main(["compare", str(tmp_path / "r"), "--vs", "ref", "--out", str(out)]) == 0
    assert (out / "paired.png").is_file() and not (out / "aggregate.png").exists()
    assert "No aggregate.png or profile.png: every method has one run" in (out / "compare.md").read_text()
    argv = [
        "compare",
        str(tmp_path / "r"),
        "--pairs",
        "a:ref",
        "--pairs",
        "b:ref,a:b",
        "--out",
        str(tmp_path / "o3"),
    ]
    assert main(argv) == 0  # a repeated --pairs adds its pairs (it once kept only the last)
    rows = (tmp_path / "o3" / "paired.csv").read_text().splitlines()[1:]
    assert sorted(tuple(r.split(",")[1:3]) for r in rows) == [("a", "b"), ("a", "ref"), ("b", "ref")]
    assert main(["compare", str(tmp_path / "r"), "--pairs", "a", "--out", str(tmp_path / "o2")]) == 2
    assert "expected pairs of two method names" in capsys.readouterr().err
