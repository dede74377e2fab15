"""The reference rows (catmip_env.planners.reference): what each knows shows in what it scores on the
same maps, the walk bound bounds every played rescue, only the project's references hold the class
reference, and the board shows them in their own table under the ranked one, never ranked."""

from __future__ import annotations

import json

import numpy as np
import pytest

from catmip_rl.benchmark.entry import method_class
from catmip_rl.benchmark.leaderboard import EntryError, leaderboard_rows, load_entries, render_leaderboard
from catmip_rl.benchmark.suite import run_suite
from catmip_rl.evaluation.evaluate import EvalSetting, evaluate
from catmip_rl.evaluation.methods import parse_method

MAPS = 24


@pytest.fixture(scope="module")
def played():
    """Each row's rescue ticks on the same 24 Task-2 maps at sigma 2 (validation seed)."""
    setting = EvalSetting("task2", "2")
    names = ("rrt-relay-coord", "news-instant", "target-known", "full-comm", "walk-bound")
    return {
        name: np.array([r["rescue_tick"] for r in evaluate(name, setting, MAPS, seed=1000).episodes])
        for name in names
    }


def _by_100(ticks: np.ndarray) -> float:
    return float(((ticks >= 0) & (ticks <= 100)).mean())


def test_the_walk_bound_is_below_every_played_rescue(played):
    bound = played["walk-bound"]
    assert (bound > 0).all()
    for name, ticks in played.items():
        rescued = ticks >= 0
        assert (bound[rescued] <= ticks[rescued]).all(), name


def test_knowing_more_scores_more_on_the_same_maps(played):
    base = _by_100(played["rrt-relay-coord"])
    assert _by_100(played["target-known"]) > base
    assert _by_100(played["target-known"]) >= _by_100(played["news-instant"]) >= base
    assert (played["news-instant"] != played["rrt-relay-coord"]).any()


def test_full_comm_is_the_planner_with_full_communication_on_the_settings_maps(played):
    full = evaluate("rrt-relay-coord", EvalSetting("task2", "full"), MAPS, seed=1000)
    assert (played["full-comm"] == [r["rescue_tick"] for r in full.episodes]).all()
    assert (played["full-comm"] != played["rrt-relay-coord"]).any()


def test_only_the_projects_references_are_of_class_reference(tmp_path):
    assert method_class("news-instant", [parse_method("news-instant")]) == "reference"
    (tmp_path / "p.py").write_text("def make_policy(cfg, seed):\n    return None\n")
    mine = parse_method(f"py:{tmp_path / 'p.py'}:make_policy")
    with pytest.raises(ValueError, match="only the project's reference rows are references"):
        method_class("p", [mine], "reference")
    with pytest.raises(ValueError, match="but walk-bound is a reference"):
        method_class("walk-bound", [parse_method("walk-bound")], "planner")
    with pytest.raises(ValueError, match="did you mean news-instant"):
        parse_method("news-instnt")


@pytest.fixture(scope="module")
def board(tmp_path_factory):
    out = tmp_path_factory.mktemp("refs")
    run_suite(
        ["nearest", "random-frontier", "walk-bound", "news-instant"], out / "s", episodes=2, progress=False
    )
    return out / "s" / "entries"


def test_the_board_shows_references_under_the_ranked_rows_never_ranked(board, tmp_path):
    rows = leaderboard_rows(load_entries(board, episodes=2, split="validation"))
    assert [r["class"] for r in rows][-2:] == ["reference", "reference"]
    assert [r["rank"] for r in rows if r["class"] == "reference"] == [None, None]
    assert all(r["rank"] for r in rows if r["class"] != "reference")
    paths = render_leaderboard(board, tmp_path / "page", episodes=2, split="validation")
    page = paths[0].read_text()
    ranked, refs = page.split("**Reference rows** (not ranked)")
    assert "| nearest |" in ranked and "walk-bound" not in ranked
    assert "| – | walk-bound | reference |" in refs and "| – | news-instant | reference |" in refs
    assert "- `walk-bound`: true map and target known at tick 0" in refs
    assert paths[1].stat().st_size > 10_000


def test_a_reference_class_on_another_method_is_refused(board, tmp_path):
    entry = json.loads((board / "nearest.json").read_text())
    (tmp_path / "nearest.json").write_text(json.dumps(entry | {"class": "reference"}))
    with pytest.raises(EntryError, match="class reference belongs to the project's reference rows"):
        load_entries(tmp_path, episodes=2, split="validation")
    entry = json.loads((board / "walk-bound.json").read_text())
    (tmp_path / "nearest.json").write_text(json.dumps(entry | {"class": "planner"}))
    with pytest.raises(EntryError, match="class reference belongs"):
        load_entries(tmp_path, episodes=2, split="validation")


@pytest.mark.parametrize("spec", [" news-instant", "news-instant ", "sync:news-instant"])
def test_a_reference_row_in_disguise_is_refused(board, tmp_path, spec):
    """Another spelling of a reference row's spec plays the reference: it is refused under any class,
    and so is a reference row under another method's name."""
    entry = json.loads((board / "news-instant.json").read_text())
    runs = [entry["runs"][0] | {"spec": spec}]
    (tmp_path / "x.json").write_text(json.dumps(entry | {"runs": runs, "class": "planner", "method": "mine"}))
    with pytest.raises(EntryError, match="plays the reference row 'news-instant'"):
        load_entries(tmp_path, episodes=2, split="validation")
    (tmp_path / "x.json").write_text(json.dumps(entry | {"method": "my-ceiling"}))
    with pytest.raises(EntryError, match="a reference row's entry is method news-instant"):
        load_entries(tmp_path, episodes=2, split="validation")
