"""catmip bench suite and catmip leaderboard: a user's policy file gives an entry the leaderboard
accepts; an interrupted suite resumes; an entry with other maps, a missing setting, a number its ticks
do not give, an unbounded or unescaped field is refused with one line naming the file; ``--vs`` pairs
every entry with one. Replays: tests/rl/evaluation/test_replay.py."""

from __future__ import annotations

import json
import re
import textwrap
from hashlib import sha256

import numpy as np
import pytest

from catmip_rl.benchmark import jobs
from catmip_rl.benchmark.entry import SETTINGS, entry_actions
from catmip_rl.benchmark.leaderboard import EntryError, load_entries, paired_rows
from catmip_rl.benchmark.suite import run_suite
from catmip_rl.cli.main import main

POLICY = textwrap.dedent(
    """
    from pathlib import Path

    class FirstAllowed:
        deterministic = True
        files = [Path(__file__).with_name("weights.bin")]  # what a learned policy would load

        def act(self, engine):
            return engine.masks.argmax(-1)

        def sampled(self, seed):  # a learned policy's sampled variant: the suite plays no such pass
            raise AssertionError("the suite played a sampled pass")

    def make_policy(env_config, seed):
        return FirstAllowed()
    """
)


@pytest.fixture(scope="module")
def suite(tmp_path_factory):
    out = tmp_path_factory.mktemp("suite")
    (out / "mine.py").write_text(POLICY)
    (out / "weights.bin").write_bytes(b"trained")
    mine = f"mine=py:{out / 'mine.py'}:make_policy"
    about = {"code": {"mine": "https://example.org/mine"}, "notes": {"mine": "first allowed goal"},
             "classes": {"mine": "learned"}, "chosen_on": {"mine": "nothing"}}  # fmt: skip
    paths = run_suite(["nearest", mine], out / "s", episodes=2, progress=False, **about)
    return out, paths


def test_a_users_policy_file_gives_an_entry_the_leaderboard_accepts(suite, capsys):
    out, paths = suite
    assert [p.name for p in paths] == ["nearest.json", "mine.json"]
    entry = json.loads(paths[1].read_text())
    assert set(entry["settings"]) == {st.label for st in SETTINGS} and entry["episodes"] == 2
    assert entry["runs"][0]["source"]["sha256"] and entry["actions"] == "argmax"
    assert (entry["split"], entry["seed"], entry["class"], entry["chosen_on"]) == (
        "validation",
        1000,
        "learned",
        "nothing",
    )
    assert entry["runs"][0]["spec"] == f"py:{out / 'mine.py'}:make_policy"
    assert json.loads(paths[0].read_text())["class"] == "planner"
    assert entry["runs"][0]["files"] == [
        {"file": str(out / "weights.bin"), "sha256": sha256(b"trained").hexdigest()}
    ]
    assert all(
        len(s["rescue_tick"]) == 1 and len(s["rescue_tick"][0]) == 2 for s in entry["settings"].values()
    )
    assert entry["machine"]["cpu_capability"] in ("AVX512", "AVX2", "DEFAULT")
    summary = json.loads((out / "s" / "runs" / SETTINGS[0].label / "mine" / "summary.json").read_text())
    assert summary["sampled_pass"] is False and "sampled_success_by_100" not in summary
    board = ["leaderboard", "--entries", str(out / "s" / "entries"), "--episodes", "2"]
    assert main([*board, "--out", str(out / "lb0")]) == 2  # the leaderboard ranks the test split's only
    assert "is on the validation split; this leaderboard ranks the test split's" in capsys.readouterr().err
    assert main([*board, "--split", "validation", "--out", str(out / "lb")]) == 0
    md = (out / "lb" / "leaderboard.md").read_text()
    assert "| – | [mine](<https://example.org/mine>) | learned |" in md  # validation: ordered, not ranked
    assert "| – | nearest | planner |" in md and "first allowed goal" in md and "(validation split)" in md
    assert "Not ranked (–): the validation split is for choosing" in md
    assert md.count("not verified") == 2
    assert (out / "lb" / "leaderboard.png").stat().st_size > 5000
    printed = capsys.readouterr().out
    assert "| rank | method |" in printed and "T3 σ2 +n" in printed
    # the leaderboard's count of maps is the suite's: an entry of fewer is a preview, not ranked
    assert main([*board[:3], "--split", "validation", "--out", str(out / "lb2")]) == 0
    md = (out / "lb2" / "leaderboard.md").read_text()
    assert md.count("(preview, 2 maps)") == 2 and "**Preview: mine**" in md


@pytest.mark.slow
def test_an_interrupted_suite_resumes_without_playing_again(suite, monkeypatch):
    out, paths = suite
    before = json.loads(paths[0].read_text())

    def no_play(*args, **kwargs):
        raise AssertionError("a complete run was played again")

    monkeypatch.setattr(jobs, "evaluate", no_play)
    again = run_suite(["nearest"], out / "s", episodes=2, progress=False)
    assert json.loads(again[0].read_text())["settings"] == before["settings"]
    # resumed without --code / --notes / --class, an entry keeps the link, notes and class it was given
    mine = run_suite([f"mine=py:{out / 'mine.py'}:make_policy"], out / "s", episodes=2, progress=False)
    kept = json.loads(mine[0].read_text())
    assert (kept["code"], kept["notes"]) == ("https://example.org/mine", "first allowed goal")
    assert (kept["class"], kept["chosen_on"]) == ("learned", "nothing")
    with pytest.raises(ValueError, match="holds other results"):  # the same folder, another method
        run_suite(["nearest=rrt"], out / "s", episodes=2, progress=False)
    (out / "weights.bin").write_bytes(b"trained again")  # the same policy file, new weights
    try:
        with pytest.raises(ValueError, match=r"played before .*weights\.bin changed"):
            run_suite([f"mine=py:{out / 'mine.py'}:make_policy"], out / "s", episodes=2, progress=False)
    finally:
        (out / "weights.bin").write_bytes(b"trained")


def test_an_entry_names_the_files_below_the_working_folder_relative_to_it(suite, monkeypatch):
    out, _paths = suite
    monkeypatch.chdir(out)  # as a clone's root: the entry holds no home folders
    monkeypatch.setattr(jobs, "evaluate", None)  # complete runs: read back, not played
    entry = json.loads(
        run_suite(["mine=py:mine.py:make_policy"], "s", episodes=2, progress=False)[0].read_text()
    )
    run = entry["runs"][0]
    assert run["target"] == "py:mine.py:make_policy" and run["source"]["file"] == "mine.py"
    assert run["files"] == [{"file": "weights.bin", "sha256": sha256(b"trained").hexdigest()}]


@pytest.mark.parametrize(
    ("tamper", "problem"),
    [
        (
            lambda e: e["settings"]["task3-sigma2-noise0-ma10"].update(maps_sha256="0" * 64),
            "not the frozen validation maps",
        ),
        (
            lambda e: e["settings"].pop("task2-sigma4-noise0.05-ma10"),
            "missing setting(s) ['task2-sigma4-noise0.05",
        ),
        (
            lambda e: e["settings"]["task2-full-noise0-ma10"].update(success_by_100=0.123),
            "is not what its rescue",
        ),
        (lambda e: e["settings"]["task2-full-noise0-ma10"]["rescue_tick"][0].pop(), "must be 2 integers"),
        (lambda e: e.update(suite="v0"), "suite is 'v0'"),
        (lambda e: e["aggregate"].update(iqm_success_by_100=0.99), "aggregate iqm_success_by_100"),
        (lambda e: e["aggregate"].update(iqm_success_by_100_ci=[0.0, 1.0]), "iqm_success_by_100_ci"),
        (
            lambda e: e["settings"]["task2-full-noise0-ma10"].update(success_by_100_ci=[0, 1]),
            "success_by_100_ci",
        ),
        (lambda e: e["settings"]["task2-full-noise0-ma10"].update(success_rate=True), "success_rate True"),
        (
            lambda e: e["settings"]["task2-full-noise0-ma10"]["rescue_tick"][0].__setitem__(0, 10**30),
            "rescue tick 1000000000000000000000000000000 is neither",
        ),
        (
            lambda e: e["settings"]["task2-full-noise0-ma10"].update(horizon=500),
            "horizon 500, the suite's is",
        ),
        (lambda e: e.update(method="rrt-fake\n| rrt-fake | 0.999 |"), "method holds a control character"),
        (lambda e: e.update(notes="x" * 300_000), "notes is 300,000 characters"),
        (lambda e: e.update(code="javascript:alert(1)"), "neither an http(s) address nor a relative path"),
        (lambda e: e.update({"class": "oracle"}), "class is 'oracle'"),
        (lambda e: e.update(extra="smuggled"), "unknown field(s) ['extra']"),
        (lambda e: e.update(runs=e["runs"] * 11), "11 training runs, at most 10"),
        (lambda e: e.update(split="test"), "seed is 1000, the leaderboard's is 20261201"),
    ],
)
def test_a_tampered_entry_is_refused_with_one_line_naming_it(suite, tmp_path, tamper, problem, capsys):
    out, paths = suite
    entry = json.loads(paths[0].read_text())
    tamper(entry)
    (tmp_path / "nearest.json").write_text(json.dumps(entry))
    with pytest.raises(EntryError, match="nearest.json refused") as err:
        load_entries(tmp_path, episodes=2, split="validation")
    assert problem in str(err.value) and "\n" not in str(err.value)
    args = ["leaderboard", "--entries", str(tmp_path), "--episodes", "2", "--split", "validation"]
    assert main([*args, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("refused: nearest.json: ") and problem in err
    assert "**Refused** (1):" in (tmp_path / "o" / "leaderboard.md").read_text()  # listed, not hidden


def test_the_committed_leaderboard_checks_and_is_up_to_date(tmp_path):
    from pathlib import Path

    from catmip_rl.benchmark.leaderboard import render_leaderboard

    root = Path(__file__).resolve().parents[3] / "leaderboard"
    entries = load_entries(root / "entries")  # every committed entry: the full suite's test split, checked
    assert {e["split"] for e in entries} == {"test"} and len(entries) >= 1
    assert {e["class"] for e in entries} <= {"planner", "learned", "hybrid", "floor", "reference"}
    out = tmp_path / "out" / "board"  # a page elsewhere links an entry's code where it lies
    vs = "rrt" if any(e["method"] == "rrt" for e in entries) else None
    paths = render_leaderboard(root / "entries", out, vs=vs, record=root / "verification.json")

    def files_linked(page: str, where: Path) -> str:
        return re.sub(r"\]\(<?(?![a-z]+://)([^)>]+)>?\)", lambda m: f"]({(where / m[1]).resolve()})", page)

    text = files_linked(paths[0].read_text(), out)
    for link in re.findall(r"\]\((/[^)]+)\)", text):
        assert Path(link).is_file(), link
    # redrawn after the last entry from the record of its check beside it (every row verified)
    committed = (root / "leaderboard.md").read_text()
    assert text == files_linked(committed, root)
    assert committed.count("| ✓ 5 replayed, 50 fresh |") == len(entries) and "not verified" not in committed
    assert not paths.refused and not paths.could_not
    if vs:
        assert paths[2].read_text() == (root / "vs_rrt.md").read_text()


@pytest.mark.slow
def test_every_committed_entry_replays_to_its_ticks(monkeypatch):
    """CI replays the project's own entries on two maps per setting and training run, drawn anew each time
    from the operating system's entropy (the seed is in the failure's message), from the clone."""
    from pathlib import Path

    from catmip_rl.benchmark.replay import replay_entry
    from catmip_rl.benchmark.verify import draw_seed

    clone = Path(__file__).resolve().parents[3]
    monkeypatch.chdir(clone)  # the entries name their files from the clone's root
    entries = load_entries(Path("leaderboard") / "entries")
    seed = draw_seed()
    for e in entries:
        try:
            assert replay_entry(e, 2, seed) == 2
        except EntryError as err:
            pytest.fail(f"replay seed {seed}: {err}")


def test_a_committed_entry_that_names_a_file_in_the_clone_was_played_from_that_file():
    """An entry's files (its model, a policy's weights) that lie in the clone hold the bytes it played:
    a model moved or replaced (amat_general.pt) takes its entry along, not someone else's results."""
    from pathlib import Path

    from catmip_rl.benchmark.replay import run_files
    from catmip_rl.store.shipped import file_sha256

    clone = Path(__file__).resolve().parents[3]
    checked = 0
    for entry in load_entries(clone / "leaderboard" / "entries"):
        for run in entry["runs"]:
            for f in run_files(run):
                if not Path(f["file"]).is_absolute():
                    assert (clone / f["file"]).is_file(), f"{entry['method']}: {f['file']}"
                    assert file_sha256(clone / f["file"]) == f["sha256"], f"{entry['method']}: {f['file']}"
                    checked += 1
    playing = sum(
        run["kind"] in ("amat", "py")
        for e in load_entries(clone / "leaderboard" / "entries")
        for run in e["runs"]
    )
    assert checked >= playing  # every model and policy run names at least its file


def test_vs_pairs_every_entry_with_the_reference_on_the_same_maps(suite, tmp_path, capsys):
    out, paths = suite
    entries = out / "s" / "entries"
    args = [
        "leaderboard",
        "--entries",
        str(entries),
        "--episodes",
        "2",
        "--split",
        "validation",
        "--out",
        str(tmp_path),
    ]
    assert main([*args, "--vs", "nearest"]) == 0
    rows = (tmp_path / "vs_nearest.csv").read_text().splitlines()[1:]
    mine, nearest = (json.loads(p.read_text())["settings"] for p in reversed(paths))
    assert len(rows) == len(SETTINGS)  # one method besides the reference, every setting
    for row, st in zip(rows, SETTINGS):
        method, cls, vs, runs, label, diff = row.split(",")[:6]
        by_100 = [[0 <= t <= 100 for t in s[st.label]["rescue_tick"][0]] for s in (mine, nearest)]
        assert (method, cls, vs, runs, label) == ("mine", "learned", "nearest", "1", st.label)
        assert float(diff) == pytest.approx(np.mean(by_100[0]) - np.mean(by_100[1]))
    md = (tmp_path / "vs_nearest.md").read_text()
    assert "| mine | learned | 1 |" in md and "| nearest |" not in md and "against nearest" in md
    assert "| method | class | runs | ahead / behind |" in capsys.readouterr().out
    before = (tmp_path / "leaderboard.md").stat().st_mtime_ns
    assert main([*args, "--vs", "rrt", "--force"]) == 2  # no entry of that name: one line, nothing written
    err = capsys.readouterr().err
    assert "--vs 'rrt' is no entry's method; the entries are ['mine', 'nearest']" in err
    assert err.count("\n") == 1
    assert not (tmp_path / "vs_rrt.md").exists()
    assert (tmp_path / "leaderboard.md").stat().st_mtime_ns == before


def test_a_paired_interval_spans_the_training_runs(suite):
    def entry(name, success):  # what load_entries gives: every setting the same (runs, maps) success
        settings = {st.label: {"success_by_100": float(np.mean(success))} for st in SETTINGS}
        checked = {"iqm": float(np.mean(success)), "iqm_ci": [0.0, 1.0], "settings": settings,
                   "success": {st.label: np.array(success, bool) for st in SETTINGS}}  # fmt: skip
        return {"method": name, "class": "learned", "runs": [{}] * len(success), "checked": checked}

    every, none = [True] * 100, [False] * 100
    entries = [entry("ref", [every, none]), entry("ahead", [every]), entry("split", [every, none])]
    ahead, split = paired_rows(entries, "ref")  # the reference's runs averaged: 0.5 on every map
    label = SETTINGS[0].label
    assert ahead[label] == (0.5, 0.5, 0.5) and (ahead["ahead"], ahead["behind"]) == (12, 0)
    diff, low, high = split[label]  # one run rescues every map, the other none: the mean hides it
    assert diff == 0.0 and low == pytest.approx(-0.5) and high == pytest.approx(0.5)
    assert (split["ahead"], split["behind"]) == (0, 0)


def test_a_missing_or_empty_folder_of_entries_is_named(tmp_path):
    with pytest.raises(EntryError, match="no such folder of entries: "):
        load_entries(tmp_path / "nope")
    with pytest.raises(EntryError, match=r"no entries \(\*\.json\) in "):
        load_entries(tmp_path)


def test_an_entry_says_when_its_model_played_with_the_loop_guard():
    assert entry_actions({"actions": "argmax", "loop_guard": True}) == "argmax + loop guard"
    assert entry_actions({"actions": "argmax", "loop_guard": False}) == "argmax"
    assert entry_actions({"actions": "its own"}) == "its own"  # planners, and results from before the key
    assert entry_actions({}) is None


def test_an_entry_names_a_shipped_model_by_its_path_in_the_clone(monkeypatch):
    from pathlib import Path

    import catmip_rl
    from catmip_rl.benchmark.entry import _shown_target
    from catmip_rl.evaluation.methods import parse_method

    monkeypatch.chdir(Path(catmip_rl.__file__).resolve().parents[1])  # the clone's root
    assert _shown_target(parse_method("amat:paper")) == "catmip_rl/models/amat_paper.pt"
    assert _shown_target(parse_method("amat-guard:general")) == "catmip_rl/models/amat_general.pt"


@pytest.mark.slow
def test_a_policy_that_breaks_mid_suite_says_what_is_kept_and_how_to_go_on(tmp_path):
    (tmp_path / "late.py").write_text(
        textwrap.dedent(
            """
            class BreaksOnTask3:
                def __init__(self, env_config):  # Task 3 with full communication: not the estimate's σ = 4
                    self.breaks = env_config.map_size >= 32 and env_config.comm_sigma is None

                def act(self, engine):
                    if self.breaks and engine.state.ticks.max() > 20:  # past the suite's checks
                        raise RuntimeError("no memory left")
                    return engine.masks.argmax(-1)

            def make_policy(env_config, seed):
                return BreaksOnTask3(env_config)
            """
        )
    )
    with pytest.raises(ValueError) as err:
        run_suite([f"late=py:{tmp_path / 'late.py'}:make_policy"], tmp_path / "s", episodes=1, progress=False,
                  classes={"late": "learned"})  # fmt: skip
    message = str(err.value)
    assert "no memory left" in message and "the 6 finished run(s) are kept" in message
    assert "--resume" in message
    assert len(list((tmp_path / "s" / "runs").rglob("run.json"))) == 6  # Task 2's six settings


def test_a_policys_class_is_stated_and_a_test_entry_says_what_it_was_chosen_on(tmp_path):
    """A ``py:`` policy states its class (the project's methods have theirs: a stated class they
    contradict is refused), and an entry on the test split says what its method was chosen on; both
    refused before anything is played."""
    (tmp_path / "p.py").write_text(POLICY)
    mine = f"mine=py:{tmp_path / 'p.py'}:make_policy"
    with pytest.raises(ValueError, match="state its class with --class mine=CLASS"):
        run_suite([mine], tmp_path / "a", episodes=1, progress=False)
    with pytest.raises(ValueError, match="--class nearest=learned, but nearest is a planner"):
        run_suite(["nearest"], tmp_path / "b", episodes=1, progress=False, classes={"nearest": "learned"})
    with pytest.raises(ValueError, match="the class must be one of planner, learned, hybrid, floor"):
        run_suite([mine], tmp_path / "c", episodes=1, progress=False, classes={"mine": "oracle"})
    with pytest.raises(
        ValueError, match="an entry on the test split states what random-uniform was chosen on"
    ):
        run_suite(["random-uniform"], tmp_path / "d", episodes=1, progress=False, split="test")
    assert not any((tmp_path / d).exists() and any((tmp_path / d).rglob("*.json")) for d in "abcd")


def test_a_duplicate_method_names_both_files_and_a_fifo_is_not_opened(suite, tmp_path):
    import os

    _out, paths = suite
    for name in ("a.json", "b.json"):
        (tmp_path / name).write_text(paths[0].read_text())
    with pytest.raises(EntryError, match=r"entries .*a\.json and .*b\.json name the same method 'nearest'"):
        load_entries(tmp_path, episodes=2, split="validation")
    (tmp_path / "b.json").unlink()
    os.mkfifo(tmp_path / "c.json")
    with pytest.raises(EntryError, match=r"c\.json refused: not a regular file"):
        load_entries(tmp_path, episodes=2, split="validation")


def test_a_method_or_note_cannot_forge_a_row_of_the_table():
    from catmip_rl.benchmark.board_page import md_text

    assert md_text("x | 0.999 |") == "x \\| 0.999 \\|"
    assert md_text("[a](javascript:b)") == "\\[a\\](javascript:b)" and md_text("<img>") == "\\<img\\>"
    assert md_text("amat_general") == "amat_general"


@pytest.mark.parametrize(
    ("tamper", "problem"),
    [
        (lambda f: (f / "run.json").unlink(), "without their record (run.json)"),
        (lambda f: _edit_episodes(f, lambda rows: rows.pop()), "episodes.json holds 1"),
        (
            lambda f: _edit_episodes(f, lambda rows: rows[1].update(map_hash=rows[0]["map_hash"])),
            "played twice",
        ),
        (lambda f: _edit_episodes(f, lambda rows: rows[0].update(map_hash="0badc0de")), "on other maps"),
        (lambda f: _edit_episodes(f, lambda rows: rows[0].update(rescue_tick=10_000, rescued=True)), "10000"),
    ],
)
def test_a_resumed_suite_checks_what_it_reads_back_as_strictly_as_a_fresh_run(tmp_path, tamper, problem):
    """A finished run's folder whose record was deleted, or whose episodes were edited with the record
    made to fit, is refused by --resume (one line naming the folder), not read into the entry."""
    run_suite(["nearest"], tmp_path / "s", episodes=2, progress=False)
    folder = tmp_path / "s" / "runs" / SETTINGS[3].label / "nearest"
    tamper(folder)
    with pytest.raises(ValueError, match=re.escape(problem)) as err:
        run_suite(["nearest"], tmp_path / "s", episodes=2, progress=False)
    assert str(folder) in str(err.value) and "\n" not in str(err.value)


def _edit_episodes(folder, change):
    """Edit a run's episodes.json (and its episodes.csv row count and summary, as a careful forger
    would), then rewrite its record so that the files' SHA-256 match."""
    from catmip_rl.store.outputs import RECORD, _sha256

    rows = json.loads((folder / "episodes.json").read_text())
    change(rows)
    (folder / "episodes.json").write_text(json.dumps(rows))
    (folder / "episodes.csv").unlink(missing_ok=True)
    record = json.loads((folder / RECORD).read_text())
    record["files"] = {n: _sha256(folder / n) for n in record["files"] if (folder / n).is_file()}
    (folder / RECORD).write_text(json.dumps(record))


def test_a_training_run_listed_twice_is_refused():
    with pytest.raises(ValueError, match="lists the training run rrt twice"):
        run_suite(["x=rrt,rrt"], "/nonexistent/never-written", episodes=1, progress=False)


def test_a_run_folder_replaced_by_a_link_is_not_written_through(tmp_path):
    """A resumed suite whose run folder (or --out) became a symbolic link refuses it in one line; nothing
    is written at the link's target."""
    import shutil

    run_suite(["nearest"], tmp_path / "s", episodes=1, progress=False)
    folder = tmp_path / "s" / "runs" / SETTINGS[0].label / "nearest"
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    shutil.rmtree(folder)
    folder.symlink_to(elsewhere, target_is_directory=True)
    with pytest.raises(ValueError, match="is a symbolic link: a grid reads and writes only its own folders"):
        run_suite(["nearest"], tmp_path / "s", episodes=1, progress=False)
    assert not any(elsewhere.iterdir())
    (tmp_path / "link").symlink_to(tmp_path / "s", target_is_directory=True)
    assert main(["bench", "suite", "--method", "nearest", "--episodes", "1", "--resume", "--no-progress",
                 "--out", str(tmp_path / "link")]) == 2  # fmt: skip


def _reseal(folder):
    """Rewrite a run's record (run.json) so that every file's SHA-256 fits again, as a forger would."""
    from catmip_rl.store.outputs import RECORD, _sha256

    record = json.loads((folder / RECORD).read_text())
    record["files"] = {n: _sha256(folder / n) for n in record["files"] if (folder / n).is_file()}
    (folder / RECORD).write_text(json.dumps(record))


@pytest.mark.parametrize("command", ["suite", "paper"])
@pytest.mark.parametrize(
    ("text", "problem"), [("[1, 2]", "holds a JSON list"), ("{'x':", "is not readable JSON")]
)
def test_a_resumed_run_whose_summary_is_no_json_object_is_named_in_one_line(
    tmp_path, capsys, command, text, problem
):
    """``--resume`` meets a run folder whose summary.json is a JSON list or no JSON: exit code 2 and one
    line naming the file, never a traceback."""
    folder = tmp_path / "s" / ("runs" if command == "suite" else "fig7") / SETTINGS[0].label / "nearest"
    folder.mkdir(parents=True)
    (folder / "summary.json").write_text(text)
    argv = ["bench", command, "--method" if command == "suite" else "--methods", "nearest", "--episodes", "1"]
    argv += ["--figure", "7", "--jobs", "1"] if command == "paper" else ["--jobs", "1"]
    assert main([*argv, "--resume", "--no-progress", "--out", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert f"{folder / 'summary.json'} {problem}" in err


@pytest.mark.parametrize(
    ("forge", "problem"),
    [
        (lambda f: _relabel(f, SETTINGS[1], SETTINGS[0]), "episode 0 has noise 0.05, not this run's 0.0"),
        (lambda f: _edit_json(f / "summary.json", mean_rescue_tick=1.0), "mean_rescue_tick 1.0"),
        (lambda f: _edit_json(f / "summary.json", horizon=500), "horizon 500 is not"),
        (lambda f: _edit_json(f / "summary.json", decisions_per_episode=3.0), "decisions_per_episode 3.0"),
        (
            lambda f: (f / "curve.csv").write_text("tick,success_rate\n0,1.0\n"),
            "curve.csv is not the success",
        ),
        (lambda f: _edit_json(f / "episodes.json", episode=0), "episode 1 has episode 0"),
    ],
)
def test_a_resumed_suite_refuses_results_that_are_not_this_runs_or_not_what_they_give(
    suite, tmp_path, forge, problem
):
    """A finished run's folder filled with another setting's results and relabelled (summary.json's label
    and setting), or holding a number its episodes do not give, its record made to fit, is refused by
    --resume in one line naming the file."""
    import shutil

    out, _paths = suite
    for st in SETTINGS:  # the suite's finished runs of nearest, to resume
        shutil.copytree(
            out / "s" / "runs" / st.label / "nearest", tmp_path / "s" / "runs" / st.label / "nearest"
        )
    target = tmp_path / "s" / "runs" / SETTINGS[0].label / "nearest"  # task2, full communication, no noise
    forge(target)
    _reseal(target)
    with pytest.raises(ValueError, match=re.escape(problem)) as err:
        run_suite(["nearest"], tmp_path / "s", episodes=2, progress=False)
    assert str(target) in str(err.value) and "\n" not in str(err.value)


def _edit_json(path, **values):
    """Set ``values`` in a JSON object, or in the last episode of a list of them."""
    value = json.loads(path.read_text())
    (value[-1] if isinstance(value, list) else value).update(values)
    path.write_text(json.dumps(value))


def _relabel(folder, source, setting):
    """``folder`` filled with the run of ``source`` beside it, its summary.json saying ``setting`` (its
    label and its setting): the same maps, another setting's results."""
    from dataclasses import asdict

    for path in (folder.parent.parent / source.label / "nearest").iterdir():
        (folder / path.name).write_bytes(path.read_bytes())
    _edit_json(folder / "summary.json", label=setting.label, setting=asdict(setting))


def test_the_leaderboard_reads_no_hidden_file_a_killed_writer_left(suite, tmp_path):
    """An atomic write killed before its rename leaves ``.NAME.PID-RANDOM.tmp.json`` beside the entries:
    no entry (half written, or a second copy of one), never read."""
    _out, paths = suite
    for path in paths:
        (tmp_path / path.name).write_text(path.read_text())
    (tmp_path / ".nearest.123-0a1b2c3d.tmp.json").write_text(paths[0].read_text()[:100])  # half written
    (tmp_path / ".mine.456-0a1b2c3d.tmp.json").write_text(paths[1].read_text())  # whole, not yet renamed
    entries = load_entries(tmp_path, episodes=2, split="validation")
    assert sorted(e["file"] for e in entries) == ["mine.json", "nearest.json"]
    for path in paths:
        (tmp_path / path.name).unlink()
    with pytest.raises(EntryError, match=r"no entries \(\*\.json\) in "):
        load_entries(tmp_path, episodes=2, split="validation")


NEEDS_RESET = textwrap.dedent(
    """
    import numpy as np

    class NeedsReset:  # PettingZoo level: reset() is called before each episode
        episode = None

        def reset(self):
            self.episode = 0 if self.episode is None else self.episode + 1

        def act(self, observations, infos):
            if self.episode is None:
                raise RuntimeError("act() before reset()")
            active = [r for r in observations if infos[r]["active"]]
            return {r: int(np.argmax(observations[r]["action_mask"])) for r in active}

    def make_policy(env_config, seed):
        return NeedsReset()
    """
)


def test_the_suites_first_decision_resets_a_pettingzoo_policy_as_an_evaluation_does(tmp_path):
    """The check before any run calls a PettingZoo-level policy as the protocol says: reset(), then act."""
    from catmip_rl.evaluation.methods import parse_method

    (tmp_path / "p.py").write_text(NEEDS_RESET)
    method = parse_method(f"needs=py:{tmp_path / 'p.py'}:make_policy")
    plays, not_played = jobs.check_methods([[method]], [(SETTINGS[0].label, SETTINGS[0])], 1000)
    assert plays == {(SETTINGS[0].label, "needs"): [method]} and not not_played


def test_the_suite_prints_its_own_estimate_before_playing(tmp_path, capsys):
    """``catmip bench suite`` times the methods on a few maps of each task and prints how long the runs
    left take, before the first run; a suite with every run played prints none."""
    from catmip_rl.benchmark.estimate import duration_text

    argv = [
        "bench",
        "suite",
        "--method",
        "nearest",
        "--episodes",
        "2",
        "--jobs",
        "1",
        "--no-progress",
        "--out",
        str(tmp_path / "s"),
    ]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert re.search(r"^estimate: .+ for 12 runs on 1 job \(timed on 2 maps of each task\)$", printed, re.M)
    assert printed.index("estimate: ") < printed.index("IQM rescued")
    assert main([*argv, "--resume"]) == 0
    assert "estimate: " not in capsys.readouterr().out
    assert duration_text(30) == "under a minute" and duration_text(125) == "3 min"
    assert duration_text(2 * 3600 + 9 * 60) == "2 h 10 min" and duration_text(3 * 3600) == "3 h"
