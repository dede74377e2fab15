"""training.allocator: glibc's malloc keeps freed large blocks, so repeated large allocations stop
faulting."""

import os
import subprocess
import sys

import pytest

CHILD = """
import resource, sys
import numpy as np
from catmip_rl.training.allocator import keep_freed_memory
if sys.argv[1] == "on":
    assert keep_freed_memory()
def step():  # like a training step: eight 16 MB activations alive at once, then all freed
    return sum(float(a[-1]) for a in [np.ones(16 << 20, np.uint8) for _ in range(8)])
step()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(10):
    step()
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(mode: str) -> int:
    out = subprocess.run([sys.executable, "-c", CHILD, mode], capture_output=True, text=True, check=True)
    return int(out.stdout.strip())


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc malloc tuning is Linux-only")
def test_keep_freed_memory_stops_page_faults_on_repeated_large_blocks():
    off, on = _faults("off"), _faults("on")
    assert off > 10 * 2000  # glibc trims the freed heap top: each step faults fresh pages in (4 KB each)
    assert on < off / 20


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc malloc tuning is Linux-only")
def test_keep_freed_memory_can_be_turned_off():
    env = {**os.environ, "CATMIP_KEEP_HEAP": "0"}
    code = "from catmip_rl.training.allocator import keep_freed_memory; print(keep_freed_memory())"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env)
    assert out.stdout.strip() == "False"
