"""A leaderboard replay compares ticks exactly: AMAT's argmax play gives the same rescue ticks whatever
the torch thread count, the batch the maps are played in, and the CPU's vector instructions (AVX-512
against AVX2, forced through ATen's, oneDNN's and MKL's switches in a subprocess); so do the torch
``py:`` policies of the MAPPO and IPPO entries (the replay plays on one thread, a suite may have
played on two)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from catmip_rl.evaluation.evaluate import EvalSetting, evaluate
from catmip_rl.evaluation.workers import torch_threads

SETTING = EvalSetting("task2", "2", 0.05)
SEED = 20261201
MARL = Path(__file__).resolve().parents[3] / "run-records" / "marl-pool4" / "policies.py"

PLAY = """
import json, sys
from catmip_rl.evaluation.evaluate import EvalSetting, evaluate
from catmip_rl.evaluation.workers import torch_threads
torch_threads(1)
r = evaluate("amat:general", EvalSetting("task2", "2", 0.05), 6, 20261201, sampled_too=False)
print(json.dumps([e.get("rescue_tick") for e in r.episodes]))
"""


def _ticks(method: str, episodes: int, threads: int, setting: EvalSetting = SETTING) -> list:
    torch_threads(threads)
    try:
        result = evaluate(method, setting, episodes, SEED, sampled_too=False)
    finally:
        torch_threads(1)
    return [e.get("rescue_tick") for e in result.episodes]


@pytest.mark.parametrize("method", ["amat:general", "amat:task1"])
def test_argmax_play_does_not_depend_on_threads_or_the_batch(method):
    batch = _ticks(method, 12, threads=1)
    assert _ticks(method, 12, threads=2) == batch
    assert _ticks(method, 4, threads=2) == batch[:4]


@pytest.mark.slow
@pytest.mark.parametrize("factory", ["mappo_s0", "ippo_s1"])
@pytest.mark.parametrize("task", ["task2", "task3"])
def test_the_marl_entries_policies_play_alike_on_one_thread_and_two(factory, task):
    method, setting = f"py:{MARL}:{factory}", EvalSetting(task, "2", 0.05)
    assert _ticks(method, 6, threads=2, setting=setting) == _ticks(method, 6, threads=1, setting=setting)


@pytest.mark.slow
def test_argmax_play_is_the_same_with_avx2_kernels():
    def run(extra: dict[str, str]) -> list:
        env = {**os.environ, **extra}
        out = subprocess.run(
            [sys.executable, "-c", PLAY], env=env, capture_output=True, text=True, check=True
        )
        return json.loads(out.stdout.strip().splitlines()[-1])

    avx2 = {"ATEN_CPU_CAPABILITY": "avx2", "ONEDNN_MAX_CPU_ISA": "AVX2", "MKL_ENABLE_INSTRUCTIONS": "AVX2"}
    assert run(avx2) == run({})
