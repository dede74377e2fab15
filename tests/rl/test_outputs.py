"""Outputs that hold one run's results or none: one writer per output (a second is refused naming the
first), results moved in with their record last, ``--force`` replacing earlier results, debris of a
killed writer removed, workers that die with their parent, ``sys.exit`` in a policy reported."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from catmip_rl.benchmark.results import load_results
from catmip_rl.cli.main import main
from catmip_rl.store.outputs import (
    RECORD,
    OutputInUse,
    check_record,
    commit_results,
    holding,
    output_folder,
    remove_debris,
    remove_results,
    staging_dir,
)
from tests.rl.helpers import one_line_error

EVAL = ["eval", "--method", "nearest", "--task", "task1", "--episodes", "3", "--no-progress"]


def test_a_held_folder_refuses_a_second_writer_naming_the_first(tmp_path, capsys):
    out = tmp_path / "out"
    with holding(out, "--out"):
        with pytest.raises(OutputInUse, match=f"process {os.getpid()}"):
            holding(out, "--out").acquire()
        assert main([*EVAL, "--out", str(out)]) == 2
        one_line_error(capsys, f"--out {out} is in use by process {os.getpid()}")
        assert sorted(p.name for p in out.iterdir()) == [".lock"]  # nothing written
    assert not (out / ".lock").exists()  # released: the lock file goes
    assert main([*EVAL, "--out", str(out)]) == 0
    assert check_record(out)["files"].keys() == {"curve.csv", "curve.png", "episodes.csv", "episodes.json",
                                                 "summary.json"}  # fmt: skip


def test_two_catmip_evals_into_one_folder_leave_one_runs_results(tmp_path, capsys):
    """The bar: a second ``catmip eval`` while the first runs is refused with one line naming the first,
    and the folder ends with exactly the first's results."""
    assert main([*EVAL, "--out", str(tmp_path / "warm")]) == 0  # compiled here: the second starts at once
    out = tmp_path / "out"
    first = subprocess.Popen(
        [sys.executable, "-m", "catmip_rl.cli", "eval", "--method", "nearest", "--task", "task1",
         "--episodes", "1000", "--no-progress", "--out", str(out)],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    deadline = time.monotonic() + 120
    while not (out / ".lock").exists() and first.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert first.poll() is None, first.stderr.read()
    assert (
        main(["eval", "--method", "random-uniform", "--episodes", "5", "--no-progress", "--out", str(out)])
        == 2
    )
    one_line_error(capsys, f"is in use by process {first.pid}")
    assert first.wait(timeout=300) == 0, first.stderr.read()
    record = check_record(out)
    assert record["process"] == first.pid
    summary = json.loads((out / "summary.json").read_text())
    assert (summary["method"], summary["episodes"]) == ("nearest", 1000)
    assert sorted(p.name for p in out.iterdir()) == sorted([*record["files"], RECORD])


def test_a_folder_mixed_by_two_runs_is_refused_by_compare(tmp_path, capsys):
    for name, method in (("a", "nearest"), ("b", "random-uniform")):
        assert main([*EVAL[:2], method, *EVAL[3:], "--out", str(tmp_path / name)]) == 0
    (tmp_path / "a" / "episodes.json").write_bytes((tmp_path / "b" / "episodes.json").read_bytes())
    with pytest.raises(ValueError, match="does not hold one run's results: episodes.json"):
        check_record(tmp_path / "a")
    capsys.readouterr()
    assert main(["compare", str(tmp_path / "a"), "--out", str(tmp_path / "cmp")]) == 2
    one_line_error(capsys, str(tmp_path / "a"), "not written by the run of its run.json")
    (tmp_path / "b" / RECORD).write_text("[]")
    with pytest.raises(ValueError, match="not a catmip results record"):
        load_results([str(tmp_path / "b")])


def test_results_are_moved_in_with_the_record_last(tmp_path):
    stage = staging_dir(tmp_path / "r")
    for name in ("summary.json", "episodes.json"):
        (stage / name).write_text(name)
    out = commit_results(stage)
    assert sorted(p.name for p in out.iterdir()) == ["episodes.json", RECORD, "summary.json"]
    assert check_record(out)["run_id"]


def test_force_replaces_earlier_results_and_debris_but_keeps_other_files(tmp_path, capsys):
    out = tmp_path / "bench"
    for method in ("nearest", "random-uniform", "utility"):
        assert main([*EVAL[:2], method, *EVAL[3:], "--out", str(out / "fig" / method)]) == 0
    (out / "notes.txt").write_text("mine")
    (out / "fig" / ".incoming-1-dead").mkdir()
    (out / "fig" / ".curves.1-dead.tmp.csv").write_text("half")
    remove_debris(out)
    assert (
        not (out / "fig" / ".incoming-1-dead").exists()
        and not (out / "fig" / ".curves.1-dead.tmp.csv").exists()
    )
    removed = remove_results(out)
    assert sorted(p.name for p in removed) == ["nearest", "random-uniform", "utility"]
    assert (out / "notes.txt").read_text() == "mine"
    # an eval's --force: the earlier run's files go, the new run's come in (its record lists them)
    assert main([*EVAL, "--out", str(tmp_path / "e")]) == 0
    (tmp_path / "e" / ".summary.9-dead.tmp.json").write_text("half")
    assert main([*EVAL[:2], "random-uniform", *EVAL[3:], "--out", str(tmp_path / "e"), "--force"]) == 0
    assert json.loads((tmp_path / "e" / "summary.json").read_text())["method"] == "random-uniform"
    assert sorted(p.name for p in (tmp_path / "e").iterdir()) == sorted(
        [*check_record(tmp_path / "e")["files"], RECORD]
    )


def test_a_failed_command_removes_the_folder_it_created(tmp_path):
    with pytest.raises(RuntimeError), output_folder(tmp_path / "new" / "out"):
        raise RuntimeError("boom")
    assert not (tmp_path / "new").exists()


def test_bench_force_with_fewer_methods_drops_the_old_method_folders(tmp_path, capsys):
    argv = ["bench", "paper", "--figure", "6", "--episodes", "2", "--jobs", "1", "--out", str(tmp_path)]
    assert main([*argv, "--methods", "nearest,random-uniform"]) == 0
    assert main([*argv, "--methods", "nearest", "--force"]) == 0
    methods = {json.loads(p.read_text())["method"] for p in (tmp_path / "fig6").rglob("summary.json")}
    assert methods == {"nearest"}
    assert not (tmp_path / ".lock").exists()


def test_bench_resume_reads_complete_runs_back_and_plays_the_rest(tmp_path, capsys, monkeypatch):
    argv = ["bench", "paper", "--figure", "6", "--episodes", "2", "--jobs", "1", "--out", str(tmp_path)]
    assert main([*argv, "--methods", "nearest"]) == 0
    first = {p: p.read_bytes() for p in (tmp_path / "fig6").rglob("episodes.json")}
    assert main([*argv, "--methods", "nearest,random-uniform"]) == 2  # not empty: --force or --resume
    assert "--resume to continue it" in capsys.readouterr().err

    from catmip_rl.benchmark import jobs

    played, evaluate = [], jobs.evaluate

    def counted(method, *args, **kwargs):
        played.append(method.name)
        return evaluate(method, *args, **kwargs)

    monkeypatch.setattr(jobs, "evaluate", counted)
    assert main([*argv, "--methods", "nearest,random-uniform", "--resume"]) == 0
    assert played == ["random-uniform"] * 3  # one run a panel; nearest's three were read back
    assert all(p.read_bytes() == b for p, b in first.items())
    rows = list(csv.DictReader((tmp_path / "fig6" / "summary.csv").open()))
    assert sorted({r["method"] for r in rows}) == ["nearest", "random-uniform"] and len(rows) == 6
    assert main([*argv, "--methods", "nearest", "--resume", "--force"]) == 2  # one or the other


_POOL_PARENT = """
import multiprocessing, sys, time
from concurrent.futures import ProcessPoolExecutor
from catmip_rl.evaluation.workers import die_with_parent
import os
if __name__ == "__main__":
    pool = ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn"),
                               initializer=die_with_parent, initargs=(os.getpid(),))
    futures = [pool.submit(time.sleep, 120) for _ in range(2)]
    time.sleep(0.5)
    print(" ".join(str(p) for p in pool._processes), flush=True)
    time.sleep(120)
"""


@pytest.mark.skipif(sys.platform != "linux", reason="the kernel's parent-death signal is Linux's")
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_workers_end_with_their_parent(tmp_path, sig):
    script = tmp_path / "parent.py"
    script.write_text(_POOL_PARENT)
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    workers = [int(p) for p in parent.stdout.readline().split()]
    assert len(workers) == 2 and all(_alive(p) for p in workers)
    parent.send_signal(sig)
    parent.wait(timeout=30)
    deadline = time.monotonic() + 20
    while any(_alive(p) for p in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(_alive(p) for p in workers)


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0]
    except FileNotFoundError:
        return False
    return state != "Z"  # a zombie has ended (its parent, init, reaps it)


def test_a_failed_bench_leaves_no_partial_figure(tmp_path, capsys):
    policy = tmp_path / "quits.py"
    policy.write_text("import sys\nclass P:\n    def act(self, engine):\n        sys.exit(0)\n"
                      "def make(env_config, seed):\n    return P()\n")  # fmt: skip
    out = tmp_path / "bench"
    argv = ["bench", "paper", "--figure", "6", "--methods", "nearest", "--method", f"py:{policy}:make",
            "--episodes", "2", "--jobs", "1", "--out", str(out)]  # fmt: skip
    assert main(argv) == 2
    assert "SystemExit(0)" in capsys.readouterr().err
    assert not out.exists()  # the nearest runs it finished went with the figure


@pytest.mark.parametrize("where", ["act", "factory"])
@pytest.mark.parametrize("code", [0, 3])
def test_sys_exit_in_a_policy_is_one_line_and_exit_2(tmp_path, capsys, where, code):
    policy = tmp_path / "quits.py"
    policy.write_text(
        "import sys\n"
        "class P:\n"
        "    def act(self, engine):\n"
        f"        sys.exit({code})\n"
        "def make(env_config, seed):\n"
        + (f"    sys.exit({code})\n" if where == "factory" else "    return P()\n")
    )
    out = tmp_path / "out"
    assert (
        main(["eval", "--method", f"py:{policy}:make", "--episodes", "2", "--no-progress", "--out", str(out)])
        == 2
    )
    one_line_error(capsys, "SystemExit", "sys.exit()")
    assert not out.exists()


def _hammer(out: str, rounds: int, errors) -> None:
    """Take and release ``out``'s lock ``rounds`` times; inside, a sentinel file must not exist."""
    sentinel = Path(out) / "held"
    done = 0
    while done < rounds:
        try:
            lock = holding(out).acquire()
        except OutputInUse:
            continue
        try:
            if sentinel.exists():
                errors.put("two holders at once")
            sentinel.touch()
            time.sleep(0.0005)
            sentinel.unlink()
        finally:
            lock.release()  # removes the lock file: the next holder locks a new one
        done += 1


def test_concurrent_writers_never_hold_one_output_together(tmp_path):
    """Four processes racing for one output's lock (each release removes the lock file, so a racer may
    lock a file just removed: it must notice and try again) never overlap."""
    import multiprocessing

    ctx = multiprocessing.get_context("fork" if sys.platform == "linux" else "spawn")
    errors = ctx.Queue()
    procs = [ctx.Process(target=_hammer, args=(str(tmp_path), 40, errors)) for _ in range(4)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(timeout=120)
    assert all(p.exitcode == 0 for p in procs)
    assert errors.empty()
    assert not (tmp_path / ".lock").exists()
