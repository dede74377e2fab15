"""catmip leaderboard --replay K --fresh M: every run played again on maps chosen at verification time and
on fresh maps, judged by the fresh-map rule; copies, runs listed twice and forged ticks refused and listed
under the table, the honest entries ranked, a preview placed against the board, the record beside the
page."""

from __future__ import annotations

import json

import numpy as np
import pytest

from catmip_rl.benchmark import fresh_rule
from catmip_rl.benchmark.entry import SETTINGS, iqm_interval, rescued_by_100, setting_numbers
from catmip_rl.benchmark.replay import replay_indices
from catmip_rl.benchmark.suite import run_suite
from catmip_rl.benchmark.verify import twin_refusals
from catmip_rl.cli.main import main

LABELS = [st.label for st in SETTINGS]


def _board(folder, out, *extra, episodes=3):
    return ["leaderboard", "--entries", str(folder), "--episodes", str(episodes), "--no-progress",
            "--jobs", "1", "--out", str(out), *extra]  # fmt: skip


def _restate(entry: dict) -> dict:
    """Every number of ``entry`` recomputed from its (edited) ticks: what a forger would do."""
    for s in entry["settings"].values():
        s.update(setting_numbers(np.array(s["rescue_tick"]), s["horizon"]))
    success = [rescued_by_100(np.array(s["rescue_tick"]), s["horizon"]) for s in entry["settings"].values()]
    iqm, low, high = iqm_interval(success)
    entry["aggregate"] = {"iqm_success_by_100": iqm, "iqm_success_by_100_ci": [low, high]}
    return entry


@pytest.fixture(scope="module")
def suite(tmp_path_factory):
    out = tmp_path_factory.mktemp("verify")
    about = {"chosen_on": {m: "nothing" for m in ("nearest", "random-uniform")}}
    run_suite(["nearest", "random-uniform"], out / "s", episodes=3, progress=False, split="test", **about)
    return out


# -- the rule ----------
def test_the_gap_is_positive_where_a_run_plays_below_its_claim():
    assert fresh_rule.gap_z(0.8, 1000, 20, 50) > 5 > 0 > fresh_rule.gap_z(0.3, 1000, 30, 50)


def test_the_rule_refuses_one_short_setting_and_a_pooled_shortfall_not_an_honest_run():
    claimed = dict.fromkeys(LABELS, 0.5)
    honest = dict.fromkeys(LABELS, 25)
    assert not fresh_rule.judge_run(claimed, 1000, honest, 50).refused
    short = honest | {LABELS[3]: 8}  # 0.16 played where 0.5 is claimed
    assert fresh_rule.suspicious(claimed, 1000, short, 50) == [LABELS[3]]
    verdict = fresh_rule.judge_run(claimed, 1000, short, 50, {LABELS[3]: (30, 150)})
    assert (
        verdict.refused
        and verdict.reason.startswith(LABELS[3])
        and verdict.settings[LABELS[3]]["maps"] == 200
    )
    pooled = dict.fromkeys(LABELS, 19)  # 0.38 everywhere: each setting within its noise, the mean not
    verdict = fresh_rule.judge_run(claimed, 1000, pooled, 50)
    assert verdict.refused and verdict.reason.startswith("pooled over the settings")


def test_calibration_measures_false_refusals_and_power_on_entries(suite):
    from catmip_rl.benchmark.entry_check import load_entries

    entries = load_entries(suite / "s" / "entries", 3)
    found = fresh_rule.calibrate(entries, draws=20)
    assert set(found["false_refusal"]) == {"nearest", "random-uniform"}
    assert all(0 <= v <= 1 for rates in found["false_refusal"].values() for v in rates.values())
    assert 0 <= found["power_pooled_0.10"]["min"] <= 1


# -- replayed maps ----------
def test_replayed_maps_are_drawn_from_the_seed_and_repeat_with_it():
    picks = replay_indices(123, "mine", 0, LABELS[0], 1000, 5)
    assert picks == replay_indices(123, "mine", 0, LABELS[0], 1000, 5) and picks == sorted(set(picks))
    assert picks != replay_indices(124, "mine", 0, LABELS[0], 1000, 5) and picks != list(range(5))
    assert replay_indices(1, "mine", 0, LABELS[0], 7, None) == list(range(7))


# -- copies ----------
def _fake(name, created, runs):
    ticks = {label: np.array(runs) for label in LABELS}
    return {"method": name, "created": created, "file": f"{name}.json", "runs": [{}] * len(runs),
            "settings": {label: {"rescue_tick": t.tolist()} for label, t in ticks.items()}}  # fmt: skip


def test_a_renamed_copy_and_a_run_listed_twice_are_refused_from_their_ticks():
    a = list(range(100))
    b = [t if t % 10 else -1 for t in a]  # 10 % of the maps differ
    entries = [
        _fake("original", "2026-12-01", [a]),
        _fake("copy", "2026-12-05", [[*a[:97], -1, -1, -1]]),  # 97 % the same
        _fake("twice", "2026-12-02", [b, b]),
        _fake("other", "2026-12-03", [b]),
    ]
    refused = twin_refusals(entries)
    assert set(refused) == {"copy", "twice", "other"}
    assert refused["copy"].startswith("plays as original")
    assert "a run listed twice" in refused["twice"]
    assert refused["other"].startswith("plays as twice")  # the earlier entry stands


# -- the whole check ----------
def test_a_check_writes_its_record_and_the_page_renders_from_it(suite, capsys):
    out = suite / "lb"
    assert main(_board(suite / "s" / "entries", out, "--replay", "2", "--fresh", "4", "--seed", "77")) == 0
    printed = capsys.readouterr().out
    assert "verification seed 77" in printed
    record = json.loads((out / "verification.json").read_text())
    assert record["seed"] == 77 and record["replay"] == 2 and record["fresh"] == 4
    for name in ("nearest", "random-uniform"):
        said = record["entries"][name]
        assert said["outcome"] == "verified", said
        (run,) = said["runs"]
        assert set(run["replayed"]) == set(LABELS) and all(len(v) == 2 for v in run["replayed"].values())
        assert set(run["fresh"]) == set(LABELS) and all(s["maps"] in (4, 16) for s in run["fresh"].values())
    md = (out / "leaderboard.md").read_text()
    assert md.count("✓ 2 replayed, 4 fresh") == 2 and "fresh 4: played vs claimed" in md
    assert "seed 77" in md
    page = md
    assert main(_board(suite / "s" / "entries", out, "--force")) == 0  # no check: rendered from the record
    assert (out / "leaderboard.md").read_text() == page


def test_forged_ticks_and_a_copy_are_refused_under_the_table_and_the_rest_ranked(suite, tmp_path, capsys):
    entries = tmp_path / "entries"
    entries.mkdir()
    for name in ("nearest", "random-uniform"):
        (entries / f"{name}.json").write_text((suite / "s" / "entries" / f"{name}.json").read_text())
    forged = json.loads((entries / "random-uniform.json").read_text())
    for s in forged["settings"].values():  # rescued on every map at tick 40, every number restated
        s["rescue_tick"] = [[40] * len(run) for run in s["rescue_tick"]]
    (entries / "random-uniform.json").write_text(json.dumps(_restate(forged)))
    copy = json.loads((entries / "nearest.json").read_text()) | {"method": "mine", "created": "2099-01-01"}
    (entries / "mine.json").write_text(json.dumps(copy))
    (entries / "broken.json").write_text("{")
    code = main(_board(entries, tmp_path / "lb", "--replay", "1", "--fresh", "4", "--seed", "5"))
    assert code == 2
    err = capsys.readouterr().err
    md = (tmp_path / "lb" / "leaderboard.md").read_text()
    assert "| 1 | nearest |" in md and "| random-uniform |" not in md and "| mine |" not in md
    refused = md.split("**Refused** (3):")[1]
    assert "`mine.json`: plays as nearest" in refused and "`broken.json`: unreadable" in refused
    assert "`random-uniform.json`:" in refused
    lines = err.strip().splitlines()
    assert len(lines) == 3 and all(line.startswith("refused: ") for line in lines) and "Traceback" not in err
    assert "random-uniform.json: replaying map" in err or "random-uniform.json: run 0 on fresh maps" in err


def test_a_preview_is_placed_against_the_board_on_its_maps_not_ranked(suite, tmp_path, capsys):
    entries = tmp_path / "entries"
    entries.mkdir()
    for name in ("nearest", "random-uniform"):
        (entries / f"{name}.json").write_text((suite / "s" / "entries" / f"{name}.json").read_text())
    run_suite(["rrt"], tmp_path / "p", episodes=2, progress=False, split="test", chosen_on={"rrt": "nothing"})
    (entries / "rrt.json").write_text((tmp_path / "p" / "entries" / "rrt.json").read_text())
    assert main(_board(entries, tmp_path / "lb")) == 0
    md = (tmp_path / "lb" / "leaderboard.md").read_text()
    table, preview = md.split("**Preview: rrt**")
    assert "| rrt" not in table and "on the first 2 maps of every setting" in preview
    assert "rrt (preview, 2 maps)" in preview and preview.count("| – |") == 3


@pytest.mark.slow
def test_a_committed_entrys_check_repeats_from_its_record(monkeypatch):
    """The committed record is what a check gives: one planner entry, drawn anew each time (its name is
    in the failure's message), verified again from the record's seed gives the record's replayed maps
    and fresh-map numbers (planners decide alike on every CPU)."""
    import secrets
    from pathlib import Path

    from catmip_rl.benchmark.entry_check import load_entries
    from catmip_rl.benchmark.verify import verify_run

    clone = Path(__file__).resolve().parents[3]
    monkeypatch.chdir(clone)  # the entries name their files from the clone's root
    record = json.loads(Path("leaderboard/verification.json").read_text())
    entries = load_entries(Path("leaderboard") / "entries")
    planners = [e for e in entries if all(run["kind"] == "planner" for run in e["runs"])]
    entry = planners[secrets.randbelow(len(planners))]
    said = record["entries"][entry["method"]]
    plain = {k: v for k, v in entry.items() if k != "checked"}
    again = verify_run(plain, 0, record["seed"], record["replay"], record["fresh"])
    assert said["outcome"] == "verified" and "error" not in again, entry["method"]
    (recorded,) = said["runs"]
    assert again["replayed"] == recorded["replayed"], entry["method"]
    assert again["fresh"] == recorded["fresh"], entry["method"]  # JSON keeps a float exactly
    assert again["pooled"] == recorded["pooled"], entry["method"]


def test_a_backdated_copy_does_not_displace_the_entry_the_last_check_verified():
    a = list(range(100))
    original, thief = _fake("rrt", "2026-12-01", [a]), _fake("my-planner", "2020-01-01", [a])
    assert set(twin_refusals([original, thief])) == {"rrt"}  # by the dates they state alone
    refused = twin_refusals([original, thief], known=frozenset({"rrt"}))  # the last check verified rrt
    assert list(refused) == ["my-planner"] and refused["my-planner"].startswith("plays as rrt")


def test_a_record_edited_by_hand_is_refused_in_one_line(suite, tmp_path, capsys):
    entries, out = suite / "s" / "entries", tmp_path / "lb"
    assert main(_board(entries, out, "--replay", "1", "--fresh", "4", "--seed", "9")) == 0
    capsys.readouterr()
    record = json.loads((out / "verification.json").read_text())
    (run,) = record["entries"]["nearest"]["runs"]
    label = next(lb for lb, s in run["fresh"].items() if s["maps"] == 4)
    run["fresh"][label]["played"] = 0.0 if run["fresh"][label]["claimed"] > 0.5 else 1.0
    run["fresh"][label]["claimed"] = 1.0  # not the entry's claim either
    (out / "verification.json").write_text(json.dumps(record))
    assert main(_board(entries, out, "--force")) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is not what a check of these entries writes (nearest: run 0" in err
    (out / "verification.json").write_text(json.dumps(record | {"entries": []}))
    assert main(_board(entries, out, "--force")) == 2
    assert "(it has no entries object)" in capsys.readouterr().err


def test_bidirectional_controls_are_no_text_an_entry_may_hold():
    from catmip_rl.benchmark.entry_check import check_stated

    with pytest.raises(ValueError, match="control character"):
        check_stated("method", "rrt\u202e1.0")
