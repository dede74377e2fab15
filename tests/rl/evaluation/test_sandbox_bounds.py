"""Someone else's code is bounded in the sandbox's worker: a policy that never answers is ended at its time
limit in one line, one that grows past the memory limit likewise, every process a policy starts (detached
ones included) is gone when the evaluation ends, however it ends, and the worker writes in a temporary
folder of its own, removed at the end."""

from __future__ import annotations

import os
import sys
import textwrap
import time
import uuid
from pathlib import Path

import pytest

from catmip_rl.cli.main import main
from catmip_rl.evaluation import bounds
from catmip_rl.evaluation.evaluate import EvalSetting, evaluate
from catmip_rl.evaluation.user_policy import PolicyError

SETTING = EvalSetting("task1")

POLICIES = textwrap.dedent(
    """
    import os, signal, subprocess, sys, time
    from pathlib import Path

    MARK, NOTES = {mark!r}, Path({notes!r})

    def _sleeper(**kw):  # a child whose command line holds the test's mark
        return subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)", MARK], **kw)

    def _double_fork():
        if os.fork() == 0:  # the child: a new session, a grandchild, then gone
            os.setsid()
            if os.fork() == 0:
                os.execv(sys.executable, [sys.executable, "-c", "import time; time.sleep(600)", MARK])
            os._exit(0)

    def _spawn():
        _sleeper()
        _sleeper(start_new_session=True)
        _double_fork()

    class Honest:
        def act(self, engine):
            return engine.masks.argmax(-1)

    class Sleeps:
        def act(self, engine):
            time.sleep(10**6)

    class Dies:
        def act(self, engine):  # its children go to init, unseen: found by the worker's marker
            _spawn()
            time.sleep(0.2)
            os.kill(os.getpid(), signal.SIGKILL)

    class Grows:
        def act(self, engine):
            held = []
            for _ in range(40):  # up to 4 GB, 100 MB at a time, touched
                held.append(bytearray(100 << 20))
                time.sleep(0.05)
            return engine.masks.argmax(-1)

    def make_sleeps(env_config, seed):
        _spawn()
        return Sleeps()

    def make_detached(env_config, seed):
        _spawn()
        return Honest()

    def make_dies(env_config, seed):
        return Dies()

    def make_grows(env_config, seed):
        return Grows()

    def make_slow_factory(env_config, seed):
        time.sleep(10**6)

    def make_writer(env_config, seed):
        Path("relative.txt").write_text("here")
        NOTES.write_text("\\n".join([os.getcwd(), os.environ["HOME"], os.environ["TMPDIR"]]))
        return Honest()
    """
)


@pytest.fixture
def policy(tmp_path):
    mark = f"catmip-test-{uuid.uuid4().hex}"
    path = tmp_path / "bounded.py"
    path.write_text(POLICIES.format(mark=mark, notes=str(tmp_path / "notes.txt")))
    return path, mark


def _left(mark: str) -> list[int]:
    """Live processes (not zombies) whose command line holds ``mark``."""
    found = []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
            state = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[0]
        except OSError:
            continue
        if mark.encode() in cmdline and state != "Z":
            found.append(int(pid))
    return found


def _none_left(mark: str) -> bool:
    for _ in range(20):  # a killed process may take a moment to leave /proc
        if not _left(mark):
            return True
        time.sleep(0.1)
    return False


linux = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")


@linux
def test_a_policy_that_never_answers_is_ended_at_its_limit_with_all_it_started(policy, monkeypatch):
    path, mark = policy
    monkeypatch.setattr(bounds, "DECISION_LIMIT_S", 1.0)
    monkeypatch.setattr(bounds, "DECISION_LIMIT_PER_ROBOT_S", 0.0)
    t0 = time.monotonic()
    with pytest.raises(PolicyError, match=r"policy bounded: took longer than 1 s at act\(engine\)") as err:
        evaluate(f"py:{path}:make_sleeps", SETTING, episodes=1)
    assert time.monotonic() - t0 < 30 and "\n" not in str(err.value)
    assert _none_left(mark), _left(mark)


@linux
def test_catmip_eval_says_a_hung_policy_in_one_line_and_exits_2(policy, tmp_path, monkeypatch, capsys):
    path, mark = policy
    monkeypatch.setattr(bounds, "DECISION_LIMIT_S", 1.0)
    monkeypatch.setattr(bounds, "DECISION_LIMIT_PER_ROBOT_S", 0.0)
    out = tmp_path / "out"
    args = [
        "eval",
        "--method",
        f"py:{path}:make_sleeps",
        "--episodes",
        "1",
        "--out",
        str(out),
        "--no-progress",
    ]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "took longer than 1 s at act(engine)" in err, err
    assert not out.exists() and _none_left(mark)


@linux
def test_a_slow_factory_is_ended_at_its_own_limit(policy, monkeypatch):
    path, _ = policy
    monkeypatch.setattr(bounds, "FACTORY_LIMIT_S", 1.0)
    with pytest.raises(PolicyError, match="took longer than 1 s at the factory"):
        evaluate(f"py:{path}:make_slow_factory", SETTING, episodes=1)


@linux
def test_detached_processes_a_policy_started_end_with_the_evaluation(policy):
    path, mark = policy
    result = evaluate(f"py:{path}:make_detached", SETTING, episodes=2, sampled_too=False)
    assert len(result.episodes) == 2
    assert _none_left(mark), _left(mark)


@linux
def test_a_worker_that_is_killed_leaves_none_of_its_processes(policy):
    path, mark = policy
    with pytest.raises(
        PolicyError, match=r"policy bounded: its process ended during act\(engine\) \(signal 9\)"
    ):
        evaluate(f"py:{path}:make_dies", SETTING, episodes=1)
    assert _none_left(mark), _left(mark)


@linux
def test_a_policy_past_the_memory_limit_is_ended_in_one_line(policy, monkeypatch):
    path, _ = policy
    monkeypatch.setattr(bounds, "MEMORY_LIMIT_BYTES", 1 << 30)
    over = r"policy bounded: its process used .* GiB of memory at act\(engine\), over the limit of 1 GiB"
    with pytest.raises(PolicyError, match=over):
        evaluate(f"py:{path}:make_grows", SETTING, episodes=1)


def test_the_worker_writes_in_a_folder_of_its_own_removed_at_the_end(policy, tmp_path, monkeypatch):
    path, _ = policy
    monkeypatch.chdir(tmp_path)
    evaluate(f"py:{path}:make_writer", SETTING, episodes=1, sampled_too=False)
    cwd, home, tmp = (tmp_path / "notes.txt").read_text().splitlines()
    assert Path(home).parent == Path(cwd) and Path(tmp).parent == Path(cwd)
    assert not Path(cwd).exists() and not (tmp_path / "relative.txt").exists()


def test_a_policy_cannot_read_its_evaluators_memory(tmp_path):
    """The evaluator is not dumpable and the worker gave up CAP_SYS_PTRACE: /proc/PARENT/mem (the world,
    a check's seed) is not the policy's to read, even as root (Linux)."""
    if not sys.platform.startswith("linux"):
        pytest.skip("Linux: /proc and prctl")
    policy = tmp_path / "reads.py"
    policy.write_text(
        "import os\n"
        "def make(env_config, seed):\n"
        "    parent = os.getppid()\n"
        "    try:\n"
        "        rows = open(f'/proc/{parent}/maps').read().splitlines()\n"
        "        start = int(next(r for r in rows if r.split()[1].startswith('r')).split('-')[0], 16)\n"
        "        with open(f'/proc/{parent}/mem', 'rb') as f:\n"
        "            f.seek(start)\n"
        "            f.read(16)\n"
        "    except OSError:\n"
        "        pass\n"
        "    else:\n"
        "        raise RuntimeError('read the evaluator memory')\n"
        "    return lambda obs, infos: {\n"
        "        r: int(obs[r]['action_mask'].argmax()) for r in obs if infos[r]['active']}\n"
    )
    evaluate(f"py:{policy}:make", EvalSetting("task1"), episodes=1, seed=0, sampled_too=False)
