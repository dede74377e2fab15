"""SIGTERM to a command that plays a grid on a pool of workers: it stops at once, in one line, exit code
143, its workers gone and nothing leaked (no "leaked semaphore" warning), its finished runs kept."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest


@pytest.mark.slow
def test_sigterm_stops_a_suite_cleanly(tmp_path):
    out = tmp_path / "s"
    cmd = [sys.executable, "-m", "catmip_rl.cli.main", "bench", "suite", "--method", "nearest",
           "--method", "rrt", "--episodes", "60", "--jobs", "2", "--threads", "1", "--no-progress",
           "--out", str(out)]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 240
    while not any(out.glob("runs/*/*/run.json")) and time.monotonic() < deadline:  # a run finished
        time.sleep(0.5)
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGTERM)
    _stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 143, stderr
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert lines[-1] == "catmip bench suite: terminated", stderr
    assert "leaked semaphore" not in stderr and "Traceback" not in stderr
    assert any(out.glob("runs/*/*/run.json"))  # what was finished is kept for --resume
    children = subprocess.run(["pgrep", "-P", str(proc.pid)], capture_output=True, text=True).stdout
    assert not children.strip()
    assert os.environ.get("CATMIP_DEBUG") is None
