"""catmip compare refuses results that were not played alike (other maps, seed, setting or horizon), in one
line naming two folders and what each played; --unpaired shows them side by side, marked."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import pytest

from catmip_rl.benchmark.compare import compare
from catmip_rl.benchmark.results import check_alike, load_results, played_on
from catmip_rl.cli.main import main


def _write(folder: Path, method: str, ticks: list[int | None], label: str = "task1-full-noise0-ma10",
           seed: int = 0, horizon: int = 300, first_map: int = 0) -> Path:  # fmt: skip
    folder.mkdir(parents=True)
    rows = [{"map_hash": f"{first_map + e:08x}", "rescue_tick": t} for e, t in enumerate(ticks)]
    (folder / "episodes.json").write_text(json.dumps(rows))
    summary = {"method": method, "label": label, "horizon": horizon, "seed": seed}
    (folder / "summary.json").write_text(json.dumps(summary))
    return folder


TICKS = [50] * 30 + [150] * 5 + [None] * 5


def _refused(capsys, tmp_path: Path, *args: str) -> str:
    """The one line ``catmip compare ARGS`` refused with (rc 2, nothing written to its --out); hand-made
    folders have no run.json, which a note says first."""
    out = tmp_path / "refused"
    assert main(["compare", *args, "--out", str(out)]) == 2
    lines = [line for line in capsys.readouterr().err.strip().splitlines() if not line.startswith("note: ")]
    assert len(lines) == 1 and "Traceback" not in lines[0], lines
    assert not out.exists() or not any(out.iterdir())
    return lines[0]


def test_two_eval_folders_on_other_seeds_are_refused_in_one_line_naming_both(tmp_path, capsys):
    """The bar: catmip eval of one method forgot --seed 1000; compare says so instead of an empty table."""
    a, b = tmp_path / "nearest-1000", tmp_path / "utility-0"
    assert main(["eval", "--method", "nearest", "--episodes", "3", "--seed", "1000", "--out", str(a),
                 "--no-progress"]) == 0  # fmt: skip
    assert main(["eval", "--method", "utility", "--episodes", "3", "--out", str(b), "--no-progress"]) == 0
    capsys.readouterr()
    err = _refused(capsys, tmp_path, str(a), str(b))
    pa, pb = (played_on(r) for r in load_results([str(a), str(b)]))
    assert err.startswith("catmip compare: ") and str(a) in err and str(b) in err
    assert pa.maps_sha256[:12] in err and pb.maps_sha256[:12] in err and pa.maps_sha256 != pb.maps_sha256
    assert "seed 1000 (validation split)" in err and "differ in seed and maps" in err and "--unpaired" in err
    assert main(["compare", str(a), str(b), "--unpaired", "--out", str(tmp_path / "side")]) == 0
    text = (tmp_path / "side" / "compare.md").read_text()
    assert (
        text.count("**unpaired** (maps ") == 2 and "| task1-full-noise0-ma10 | nearest | utility" not in text
    )


@pytest.mark.parametrize(
    "other, differ",
    [
        ({"seed": 1000, "first_map": 500}, "seed and maps"),  # forgot --seed
        ({"first_map": 500}, "maps"),  # other maps under the same seed (another catmip, edited)
        ({"horizon": 200}, "horizon"),
        ({"label": "task1-sigma2-noise0-ma10"}, "setting"),  # forgot --comm
        ({"label": "task1-full-noise0.05-ma10"}, "setting"),  # forgot --noise
        ({"label": "task1-full-noise0-ma5"}, "setting"),  # forgot --max-ma-ticks
    ],
)
def test_methods_not_played_alike_are_refused_naming_what_differs(tmp_path, capsys, other, differ):
    a = _write(tmp_path / "a", "a", TICKS)
    b = _write(tmp_path / "b", "b", TICKS[::-1], **other)
    err = _refused(capsys, tmp_path, str(a), str(b))
    assert f"{a} (a: task1-full-noise0-ma10, seed 0, horizon 300, 40 maps sha256 " in err
    assert f"{b} (b: " in err and f"were not played alike (they differ in {differ})" in err
    assert "so they cannot be compared map by map" in err
    with pytest.raises(ValueError, match=re.escape(f"(they differ in {differ})")):
        check_alike(load_results([str(a), str(b)]))
    check_alike(load_results([str(a), str(b)]), unpaired=True)  # allowed, marked


def test_fewer_episodes_and_a_setting_one_method_lacks_are_refused(tmp_path, capsys):
    a = _write(tmp_path / "a", "a", TICKS)
    b = _write(tmp_path / "b", "b", TICKS[:20])  # the first 20 of the same maps: not the same map set
    err = _refused(capsys, tmp_path, str(a), str(b))
    assert "40 maps" in err and "20 maps" in err and "(they differ in maps)" in err
    _write(tmp_path / "b2", "b", TICKS)
    _write(tmp_path / "a-task2", "a", TICKS, label="task2-full-noise0-ma10", first_map=900)
    err = _refused(capsys, tmp_path, str(a), str(tmp_path / "a-task2"), str(tmp_path / "b2"))
    assert f"{tmp_path / 'a-task2'} (a: task2-full-noise0-ma10" in err and str(tmp_path / "b2") in err
    assert "(b has no result in task2-full-noise0-ma10 on those maps)" in err


def test_the_runs_of_one_method_on_other_maps_are_refused_even_unpaired(tmp_path, capsys):
    a0 = _write(tmp_path / "a0", "a", TICKS)
    a1 = _write(tmp_path / "a1", "a", TICKS[::-1], seed=1000, first_map=500)
    for flags in ((), ("--unpaired",)):
        err = _refused(capsys, tmp_path, f"a={a0},{a1}", *flags)
        assert (
            str(a0) in err and str(a1) in err and "the runs of one method (a) must play the same maps" in err
        )


def test_unpaired_shows_the_rows_side_by_side_marked(tmp_path):
    _write(tmp_path / "r" / "a", "a", TICKS)
    _write(tmp_path / "r" / "b", "b", TICKS[::-1])  # the same maps as a
    _write(tmp_path / "r" / "c", "c", TICKS, seed=1000, first_map=500)  # other maps
    _write(tmp_path / "r" / "a-t2", "a", TICKS, label="task2-full-noise0-ma10", first_map=900)
    results = load_results([str(tmp_path / "r")])
    with pytest.raises(ValueError, match="were not played alike"):
        compare(results)
    report = compare(results, unpaired=True)
    assert [(r["method_a"], r["method_b"]) for r in report.paired] == [("a", "b")]  # the same maps only
    cells = {(r["method"], r["setting"]): r for r in report.by_setting}
    t1 = "task1-full-noise0-ma10"
    assert [cells[m, t1]["map_set"] for m in "abc"] == [1, 1, 2] and not any(
        cells[m, t1]["paired"] for m in "abc"
    )
    assert report.settings == [] and report.left_out == [t1, "task2-full-noise0-ma10"]  # nothing alike
    text = report.markdown()
    assert "**unpaired** (maps 2)" in text and "(b, c did not play it)" in text
    assert "  - maps 1: 40 maps of seed 0, horizon 300 (sha256 " in text and "): a, b" in text
    assert report._unpaired_notes() == {t1: "unpaired: c on other maps",
                                        "task2-full-noise0-ma10": "unpaired: b, c not played"}  # fmt: skip
    out = tmp_path / "out"
    assert main(["compare", str(tmp_path / "r"), "--unpaired", "--out", str(out)]) == 0
    with open(out / "by_setting.csv") as f:
        rows = list(csv.DictReader(f))
    assert {(r["method"], r["paired"], r["map_set"]) for r in rows if r["setting"] == t1} == {
        ("a", "False", "1"),
        ("b", "False", "1"),
        ("c", "False", "2"),
    }
    assert (out / "curves.png").stat().st_size > 0


def test_alike_results_say_what_they_were_played_on(tmp_path):
    _write(tmp_path / "a", "a", TICKS)
    _write(tmp_path / "b", "b", TICKS[::-1])
    report = compare(load_results([str(tmp_path / "a"), str(tmp_path / "b")]))
    assert all(r["paired"] for r in report.by_setting) and "unpaired" not in report.markdown()
    assert "- task1-full-noise0-ma10: every method played the same 40 maps of seed 0, horizon 300" in (
        report.markdown()
    )
