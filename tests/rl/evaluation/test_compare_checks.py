"""catmip compare refuses what a catmip eval result cannot be: each failure one line naming the folder."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from catmip_rl.benchmark.compare import compare
from catmip_rl.benchmark.results import Result, load_results
from catmip_rl.cli.main import main
from catmip_rl.evaluation.evaluate import EvalResult, EvalSetting

HORIZON = 300


def _write(folder: Path, ticks: list[int | None], method: str = "a", seed: int = 0) -> Path:
    """A result folder as ``catmip eval`` writes it (``EvalResult.write``): episodes.json / .csv with the
    columns of ``records.episode_rows``, summary.json with the keys compare reads and checks."""
    rng = np.random.default_rng(seed)  # the columns besides the outcome differ between policies
    rows = []
    for e, t in enumerate(ticks):
        rows.append({
            "method": method, "task": "task1", "comm": "full", "noise": 0.0, "max_ma_ticks": 10,
            "seed": 0, "episode": e, "map_hash": f"{e:08x}", "rescued": t is not None, "rescue_tick": t,
            "target_found_tick": None if t is None else t // 2, "rescuer_informed_tick": None,
            "explored_fraction": float(rng.random()), "ticks": HORIZON if t is None else t,
            "events": 10, "decisions": int(rng.integers(5, 50)), "stalls": 0,
        })  # fmt: skip
    n, arr = len(ticks), np.array([np.nan if t is None else t for t in ticks], float)
    summary = {"episodes": n, "horizon": HORIZON, "success_rate": float((~np.isnan(arr)).sum() / max(n, 1)),
               "success_by_100": float((arr <= 100).sum() / max(n, 1)), "method": method,
               "label": "task1-full-noise0-ma10", "seed": 0}  # fmt: skip
    EvalResult(method, EvalSetting(), 0, rows, np.zeros(HORIZON + 1), summary).write(folder)
    return folder


def _edit(folder: Path, name: str, change) -> None:
    """Rewrite ``folder/name`` (JSON) with ``change(data)`` applied, and drop the folder's record
    ``run.json`` (which would refuse the edit first): the content checks are what is tested here."""
    data = json.loads((folder / name).read_text())
    change(data)
    (folder / name).write_text(json.dumps(data))
    (folder / "run.json").unlink(missing_ok=True)


TICKS = [50] * 6 + [150] * 2 + [None] * 2


def test_a_result_as_catmip_eval_writes_it_is_accepted(tmp_path):
    (r,) = load_results([str(_write(tmp_path / "a", TICKS))])
    assert r.maps == [f"{e:08x}" for e in range(10)] and r.success.mean() == pytest.approx(0.6)
    assert np.isnan(r.rescue_tick[-1]) and r.rescue_tick[0] == 50


def test_a_result_without_episodes_is_refused(tmp_path):
    _write(tmp_path / "a", [])
    with pytest.raises(ValueError, match=r"a/episodes.json holds no episodes: a result needs at least one"):
        load_results([str(tmp_path / "a")])
    empty = Result(tmp_path / "b", "b", "s", 0, [], np.zeros(0, bool), np.zeros(0))
    with pytest.raises(ValueError, match=r"b: the result holds no episodes"):
        compare([empty])


AT = r"episode 3 \(map 00000003\) "  # the row the cases below spoil
WHOLE = "expected a whole number of ticks or null"


@pytest.mark.parametrize(
    "row, message",
    [
        ({"rescue_tick": -5, "ticks": 300}, AT + "has rescue_tick -5: a tick is never negative"),
        ({"rescue_tick": 301, "ticks": 300}, AT + r"has rescue_tick 301, beyond the horizon \(300 ticks\)"),
        ({"rescue_tick": "50"}, AT + f"has rescue_tick '50': {WHOLE}"),
        ({"rescue_tick": True}, AT + f"has rescue_tick True: {WHOLE}"),
        ({"rescue_tick": 50.5}, AT + f"has rescue_tick 50.5: {WHOLE}"),
        ({"rescue_tick": [50]}, AT + rf"has rescue_tick \[50\]: {WHOLE}"),
        ({"rescued": False}, AT + "says not rescued but its rescue_tick is 50"),
        ({"rescued": True, "rescue_tick": None}, AT + "says rescued but its rescue_tick is null"),
        ({"rescued": "yes"}, AT + "has rescued 'yes': expected true or false"),
        ({"ticks": 40}, AT + r"has rescue_tick 50 after its end \(ticks 40\)"),
        ({"ticks": 400}, AT + "has ticks 400: expected a whole number from 0 to 300"),
        ({"sampled_rescue_tick": -1}, AT + "has sampled_rescue_tick -1: a tick is never negative"),
        ({"map_hash": 7}, "episode 3 has map_hash 7: expected a non-empty string"),
    ],
)
def test_impossible_episodes_are_refused_naming_the_folder(tmp_path, row, message):
    _write(tmp_path / "bad", TICKS)
    (tmp_path / "bad" / "episodes.csv").unlink()  # the csv keeps its own values: this checks the json

    def change(rows):
        rows[3] |= row

    _edit(tmp_path / "bad", "episodes.json", change)
    with pytest.raises(ValueError, match=re.escape(f"{tmp_path / 'bad' / 'episodes.json'}: ") + message):
        load_results([str(tmp_path / "bad")])


def test_a_map_played_twice_is_refused(tmp_path):
    _write(tmp_path / "a", TICKS)
    (tmp_path / "a" / "episodes.csv").unlink()
    _edit(tmp_path / "a", "episodes.json", lambda rows: rows[7].update(map_hash=rows[2]["map_hash"]))
    with pytest.raises(
        ValueError, match=r"a/episodes.json: map 00000002 is played twice \(episodes 2 and 7\)"
    ):
        load_results([str(tmp_path / "a")])
    same = Result(tmp_path / "b", "b", "s", 0, ["x", "x"], np.ones(2, bool), np.ones(2))
    with pytest.raises(ValueError, match=r"b: map x is played twice"):
        compare([same])


def test_counts_that_disagree_between_summary_and_episodes_are_refused(tmp_path):
    ticks = [50] * 400 + [None] * 100
    a = _write(tmp_path / "a", ticks)
    _edit(a, "episodes.json", lambda rows: rows.pop())  # the summary says 500, the list holds 499
    with pytest.raises(ValueError, match=r"a: summary.json says 500 episodes but episodes.json holds 499"):
        load_results([str(a)])
    b = _write(tmp_path / "b", ticks)
    _edit(b, "summary.json", lambda s: s.update(success_by_100=0.9))
    with pytest.raises(ValueError, match=r"b: summary.json says success_by_100 0.9 but episodes.json has 400 "
                       r"of its 500 episodes rescued by tick 100 \(0.8\)"):  # fmt: skip
        load_results([str(b)])
    c = _write(tmp_path / "c", ticks)
    _edit(c, "summary.json", lambda s: s.update(success_rate=0.5))
    with pytest.raises(ValueError, match=r"c: summary.json says success_rate 0.5 but episodes.json has 400"):
        load_results([str(c)])
    d = _write(tmp_path / "d", ticks)
    _edit(d, "summary.json", lambda s: s.update(episodes="500"))
    with pytest.raises(ValueError, match=r"d: summary.json says '500' episodes but episodes.json holds 500"):
        load_results([str(d)])


def test_an_episodes_csv_that_disagrees_with_episodes_json_is_refused(tmp_path):
    a = _write(tmp_path / "a", TICKS)
    lines = (a / "episodes.csv").read_text().splitlines(keepends=True)
    (a / "episodes.csv").write_text("".join(lines[:-1]))  # 9 episodes in the csv, 10 in the json
    with pytest.raises(ValueError, match=r"a does not hold one run's results: episodes.csv missing or not"):
        load_results([str(a)])  # its record catches the edit first
    (a / "run.json").unlink()  # a folder without a record (an older catmip's): its contents catch it
    with pytest.raises(ValueError, match=r"a: episodes.csv holds 9 episodes but episodes.json holds 10"):
        load_results([str(a)])
    b = _write(tmp_path / "b", TICKS)
    _edit(b, "episodes.json", lambda rows: rows[1].update(rescue_tick=60, ticks=60))
    differ = r"b: episodes.csv and episodes.json differ at episode 1: map 00000001 rescue_tick 50 vs map "
    with pytest.raises(ValueError, match=differ + r"00000001 rescue_tick 60"):
        load_results([str(b)])


def test_a_copied_folder_is_not_a_second_training_run(tmp_path, capsys):
    a = _write(tmp_path / "run0", TICKS, method="m-seed0", seed=0)
    shutil.copytree(a, tmp_path / "copy")
    _edit(
        tmp_path / "copy", "summary.json", lambda s: s.update(method="m-seed1", seed=1)
    )  # renamed: still a copy
    same = f"{a} and {tmp_path / 'copy'} hold the same results: a copy is not a second training run"
    with pytest.raises(ValueError, match=re.escape(same)):
        compare(load_results([f"m={a},{tmp_path / 'copy'}"]))
    assert main(["compare", f"m={a},{tmp_path / 'copy'}", "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].endswith(same)
    # the same folder twice, and the same folder under a parent folder given too
    with pytest.raises(ValueError, match=re.escape(f"{a} is given twice: each result folder counts once")):
        load_results([f"m={a},{a}"])
    with pytest.raises(ValueError, match=re.escape(f"{a} is given twice")):
        load_results([str(a), str(tmp_path)])
    # hand-built results with the same maps and ticks: the same
    r = load_results([str(a)])[0]
    twin = Result(
        tmp_path / "twin", r.method, r.setting, 1, list(r.maps), r.success.copy(), r.rescue_tick.copy()
    )
    with pytest.raises(ValueError, match=r"hold the same results"):
        compare([_undigested(r), twin])
    # a second training run that happens to rescue at the same ticks is another run (its episodes differ)
    _write(tmp_path / "run1", TICKS, method="m-seed1", seed=1)
    report = compare(load_results([f"m={a},{tmp_path / 'run1'}"]))
    assert [(row["method"], row["runs"]) for row in report.by_setting] == [("m", 2)]


def _undigested(r: Result) -> Result:
    return Result(r.path, r.method, r.setting, r.seed, list(r.maps), r.success.copy(), r.rescue_tick.copy())


@pytest.mark.parametrize(
    "key, value, message",
    [
        ("label", ["task1", "task2"], r"label is \['task1', 'task2'\]: expected a non-empty string"),
        ("label", "", r"label is '': expected a non-empty string"),
        ("method", ["a"], r"method is \['a'\]: expected a non-empty string"),
        ("method", {"name": "a"}, r"method is \{'name': 'a'\}: expected a non-empty string"),
        ("horizon", "300", r"horizon is '300': expected a whole number of ticks >= 1"),
        ("seed", 1.5, r"seed is 1.5: expected a whole number"),
    ],
)
def test_summary_fields_of_the_wrong_type_are_refused_in_one_line(tmp_path, capsys, key, value, message):
    a = _write(tmp_path / "a", TICKS)
    _edit(a, "summary.json", lambda s: s.update({key: value}))
    with pytest.raises(ValueError, match=re.escape(f"{a / 'summary.json'}: ") + message):
        load_results([str(a)])
    assert main(["compare", str(a), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "summary.json" in err and "Traceback" not in err


def test_a_summary_without_a_key_is_not_a_readable_result(tmp_path):
    a = _write(tmp_path / "a", TICKS)
    _edit(a, "summary.json", lambda s: s.pop("label"))
    with pytest.raises(
        ValueError, match=r"a is not a readable catmip eval result \(summary.json has no 'label'\)"
    ):
        load_results([str(a)])
