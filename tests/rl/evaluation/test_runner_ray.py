"""``--backend ray`` on a private Ray cluster on loopback: a suite's entries equal the local pool's byte
for byte but the fields that name the machine and the date; a suite resumes across back ends; a task
whose worker died is played again; an isolated policy's worker dies with its task; a driver killed
with SIGKILL leaves no task running. Needs the distributed extra (``make test-distributed``)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

import catmip_rl.benchmark.jobs as jobs
from catmip_rl.benchmark.runner import Runner
from catmip_rl.benchmark.suite import run_suite
from catmip_rl.evaluation.bounds import MARKER
from tests.rl.evaluation import runner_helpers

pytest.importorskip("ray")
pytestmark = pytest.mark.ray

ROOT = Path(__file__).resolve().parents[3]
POLICY = textwrap.dedent(
    """
    from pathlib import Path

    import helper

    class FirstAllowed:
        deterministic = True
        files = [Path(__file__).with_name("weights.bin")]

        def act(self, engine):
            return helper.first(engine.masks)

    def make_policy(env_config, seed):
        return FirstAllowed()
    """
)
MACHINE_AND_DATE = ("machine", "played_on", "created")


@pytest.fixture(scope="module")
def suites(tmp_path_factory):
    """The same suite (a planner, a user's policy with a module and weights beside it, a reference row)
    in chunks of 2 maps, on the local pool and on Ray."""
    out = tmp_path_factory.mktemp("suites")
    (out / "policy").mkdir()
    (out / "policy" / "mine.py").write_text(POLICY)
    (out / "policy" / "helper.py").write_text("def first(masks):\n    return masks.argmax(-1)\n")
    (out / "policy" / "weights.bin").write_bytes(b"trained")
    methods = ["nearest", f"mine=py:{out / 'policy' / 'mine.py'}:make_policy", "walk-bound"]
    import ray as ray_module

    kept, jobs.CHUNK_MAPS = jobs.CHUNK_MAPS, 2
    # a cluster the suite joins and leaves running: its worker processes outlive the suite's tasks
    ray_module.init(address="local", num_cpus=2, include_dashboard=False, _node_ip_address="127.0.0.1")
    try:
        about = {"classes": {"mine": "learned"}, "progress": False}
        local = run_suite(methods, out / "local", episodes=5, jobs=1, **about)
        ray = run_suite(methods, out / "ray", episodes=5, jobs=2, backend="ray", **about)
        yield out, local, ray, methods
    finally:
        jobs.CHUNK_MAPS = kept
        ray_module.shutdown()


def _without_machine(path: Path) -> dict:
    entry = json.loads(path.read_text())
    return {k: v for k, v in entry.items() if k not in MACHINE_AND_DATE}


def test_ray_entries_equal_the_local_ones_but_the_machine_and_the_date(suites):
    _out, local, ray, _methods = suites
    for a, b in zip(local, ray):
        assert _without_machine(a) == _without_machine(b), a.name
        played = json.loads(b.read_text())["played_on"]
        assert played and all({"host", "cpu_capability"} <= set(m) for m in played)
        if json.loads(a.read_text())["played_on"] == played:  # loopback: one machine, the same bytes
            assert a.read_bytes() == b.read_bytes() or _created_differs(a, b)


def _created_differs(a: Path, b: Path) -> bool:
    return json.loads(a.read_text())["created"] != json.loads(b.read_text())["created"]


def test_a_suite_resumes_across_back_ends(suites, tmp_path):
    out, local, ray, methods = suites
    import shutil

    shutil.copytree(out / "ray", tmp_path / "s")
    for run in list((tmp_path / "s" / "runs").glob("task3-*/nearest"))[:3]:
        shutil.rmtree(run)  # a suite stopped with three runs left
    kept, jobs.CHUNK_MAPS = jobs.CHUNK_MAPS, 2
    try:
        again = run_suite(
            methods, tmp_path / "s", episodes=5, jobs=1, classes={"mine": "learned"}, progress=False
        )
    finally:
        jobs.CHUNK_MAPS = kept
    for a, b in zip(local, again):
        assert _without_machine(a) == _without_machine(b), a.name


def test_a_task_whose_worker_died_is_played_again(tmp_path):
    items = [(k, str(tmp_path)) for k in range(4)]
    assert Runner("ray", 2).map(runner_helpers.dies_once, items) == [0, 1, 4, 9]


def test_an_isolated_policys_worker_dies_with_its_task(suites):
    """Ray reuses its worker processes (the cluster still runs, its workers idle): the process an isolated
    policy played in must not outlive the task that started it."""
    assert _titled("ray::IDLE") or _titled("default_worker.py")  # the workers that played are alive
    left = []
    for pid in os.listdir("/proc"):
        try:
            env = Path(f"/proc/{pid}/environ").read_bytes()
        except (OSError, ValueError):
            continue
        if f"\0{MARKER}=".encode() in b"\0" + env:
            left.append(pid)
    assert not left


def _titled(text: str) -> list[str]:
    found = []
    for pid in os.listdir("/proc"):
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except (OSError, ValueError):
            continue
        if text in cmd:
            found.append(pid)
    return found


def test_a_driver_killed_with_sigkill_leaves_no_task_running(tmp_path):
    script = textwrap.dedent(
        """
        from catmip_rl.benchmark.runner import Runner
        from tests.rl.evaluation import runner_helpers
        Runner("ray", 2).map(runner_helpers.sleeps, [120.0] * 4)
        """
    )
    driver = subprocess.Popen([sys.executable, "-c", script], cwd=ROOT, start_new_session=True)
    try:
        deadline = time.monotonic() + 180
        while len(_titled("ray::sleeps")) < 2:
            assert driver.poll() is None and time.monotonic() < deadline, "the tasks never started"
            time.sleep(1)
        driver.send_signal(signal.SIGKILL)
        driver.wait()
        deadline = time.monotonic() + 60
        while _titled("ray::sleeps") and time.monotonic() < deadline:
            time.sleep(1)
        assert not _titled("ray::sleeps")
    finally:
        if driver.poll() is None:
            driver.kill()


def test_a_board_checked_on_ray_gives_the_local_record(suites, tmp_path, monkeypatch):
    """The same check (seed) on the local pool and as Ray tasks, each run's files shipped from the folder
    the entries' paths start in: the same record but its date and machine."""
    from catmip_rl.benchmark.leaderboard import render_leaderboard

    out, _local, _ray, _methods = suites
    import shutil

    shutil.copytree(out / "policy", tmp_path / "policy")
    monkeypatch.chdir(tmp_path)  # the entry names its files from here: policy/mine.py, policy/weights.bin
    methods = ["nearest", "mine=py:policy/mine.py:make_policy"]
    run_suite(methods, tmp_path / "s", episodes=3, jobs=1, classes={"mine": "learned"}, progress=False)
    entry = json.loads((tmp_path / "s" / "entries" / "mine.json").read_text())
    assert entry["runs"][0]["source"]["file"] == "policy/mine.py"
    records = []
    for backend, jobs_ in (("local", 1), ("ray", 2)):
        board = render_leaderboard(
            tmp_path / "s" / "entries", tmp_path / backend, 3, split="validation", replay=2, fresh=2, seed=77,
            jobs=jobs_, backend=backend,
        )  # fmt: skip
        assert not board.refused
        record = json.loads((tmp_path / backend / "verification.json").read_text())
        records.append({k: v for k, v in record.items() if k not in ("created", "machine", "played_on")})
        assert record["played_on"] and all(m["host"] for m in record["played_on"])  # who replayed the runs
    assert records[0] == records[1]
    assert records[1]["entries"]["mine"]["outcome"] == "verified"


def test_an_error_raised_in_a_task_is_raised_here_as_it_was_there():
    with pytest.raises(ValueError, match=r"^bad item 3$"):
        Runner("ray", 1).map(runner_helpers.fails, [3])


def test_a_payload_many_items_carry_goes_to_the_object_store_once(monkeypatch):
    import ray

    puts = []
    real_put = ray.put
    monkeypatch.setattr(ray, "put", lambda value, **kw: puts.append(len(value)) or real_put(value, **kw))
    payload = bytes(300_000)  # one method's files, carried by every chunk
    items = [(k, payload) for k in range(6)]
    shared = (runner_helpers.split_payload, runner_helpers.join_payload)
    out = Runner("ray", workers=2).map(runner_helpers.sized, items, shared=shared)
    assert out == [k * 300_000 for k in range(6)]
    assert puts == [300_000]
