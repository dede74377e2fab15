"""The job runner (catmip_rl.benchmark.runner) and the map chunks a grid is played in: an evaluation
played in chunks writes what one play of all its maps writes; results come back in order whatever
order they end in; a lost worker's item is played again; a policy's files travel by content and are
checked there. On Ray: tests/rl/evaluation/test_runner_ray.py (``make test-distributed``)."""

from __future__ import annotations

import hashlib
import json
from dataclasses import replace
from pathlib import Path

import pytest

import catmip_rl.benchmark.jobs as jobs
from catmip_rl.benchmark.jobs import Job, chunks_of, map_jobs
from catmip_rl.benchmark.runner import Runner
from catmip_rl.benchmark.shipping import bundle_for, played_from, restored, unpacked
from catmip_rl.evaluation.evaluate import EvalSetting, evaluate
from catmip_rl.evaluation.methods import parse_method
from tests.rl.evaluation import runner_helpers


def test_a_run_is_split_into_the_same_chunks_everywhere():
    job = Job(parse_method("nearest"), EvalSetting("task2"), 250, 1000, "x")
    assert chunks_of(job) == [(0, 100), (100, 100), (200, 50)]
    assert chunks_of(replace(job, episodes=7), 3) == [(0, 3), (3, 3), (6, 1)]


@pytest.mark.parametrize("method", ["rrt-relay-coord", "walk-bound"])
def test_an_evaluation_played_in_chunks_writes_what_one_play_writes(method, tmp_path, monkeypatch):
    setting = EvalSetting("task2", "2", 0.05)
    whole = evaluate(method, setting, 7, seed=1000)
    whole.write(tmp_path / "whole")
    monkeypatch.setattr(jobs, "CHUNK_MAPS", 3)
    (res,) = map_jobs([Job(parse_method(method), setting, 7, 1000, str(tmp_path / "chunks"))], 1, False, "")
    for name in ("episodes.json", "episodes.csv", "curve.csv"):
        assert (tmp_path / "whole" / name).read_bytes() == (tmp_path / "chunks" / name).read_bytes(), name
    one, merged = (json.loads((tmp_path / d / "summary.json").read_text()) for d in ("whole", "chunks"))
    assert merged.pop("played_on")[0]["cpu_capability"] and merged.pop("seconds") > 0
    one.pop("seconds")
    assert merged == one
    assert res["ticks"]["rescue_tick"] == [e["rescue_tick"] for e in whole.episodes]


def test_a_sampled_pass_is_keyed_per_chunk_not_per_batch():
    from catmip_rl.evaluation.played import chunk_seed

    assert chunk_seed(1000, 0) == 1000  # maps from 0: the seed an evaluation of maps 0.. always drew
    assert len({chunk_seed(1000, k) for k in (0, 100, 200)}) == 3
    assert chunk_seed(1000, 100) == chunk_seed(1000, 100) and chunk_seed(1001, 100) != chunk_seed(1000, 100)


def test_results_come_back_in_order_on_a_pool_and_each_is_reported_as_it_ends():
    seen = []
    out = Runner("local", 2).map(
        runner_helpers.square, list(range(7)), on_done=lambda k, r: seen.append((k, r))
    )
    assert out == [k * k for k in range(7)] and sorted(seen) == [(k, k * k) for k in range(7)]
    assert Runner("local", 1).map(runner_helpers.square, [3, 4]) == [9, 16]


def test_an_item_whose_worker_died_is_played_again_on_a_new_pool(tmp_path):
    items = [(k, str(tmp_path)) for k in range(4)]
    assert Runner("local", 2).map(runner_helpers.dies_once, items) == [0, 1, 4, 9]
    assert len(list(tmp_path.glob("died-*"))) == 4


def test_a_bad_runner_is_named():
    with pytest.raises(ValueError, match="backend must be one of local, ray"):
        Runner("dask")
    with pytest.raises(ValueError, match="workers must be an int >= 1"):
        Runner("local", 0)
    with pytest.raises(ValueError, match="--ray-address is for --backend ray"):
        Runner("local", 1, "auto")


def test_a_policys_folder_travels_by_content_and_is_checked_there(tmp_path):
    (tmp_path / "p").mkdir()
    (tmp_path / "p" / "mine.py").write_text("def make_policy(cfg, seed):\n    return None\n")
    (tmp_path / "p" / "run.json").write_text("{}")  # the policy's own folder holds one: still sent
    (tmp_path / "p" / "weights.bin").write_bytes(b"w")
    (tmp_path / "p" / ".git").mkdir()
    (tmp_path / "p" / ".git" / "x").write_text("hidden")
    (tmp_path / "p" / "out" / "runs" / "a").mkdir(parents=True)
    (tmp_path / "p" / "out" / "runs" / "a" / "run.json").write_text("{}")  # a result folder stays
    method = parse_method(f"py:{tmp_path / 'p' / 'mine.py'}:make_policy")
    bundle = bundle_for(method)
    assert sorted(rel for rel, _, _ in bundle.files) == ["mine.py", "run.json", "weights.bin"]
    with unpacked(bundle) as folder:
        there = played_from(bundle, method, folder)
        assert there.target == f"py:{folder / 'mine.py'}:make_policy"
        assert (folder / "mine.py").read_bytes() == (tmp_path / "p" / "mine.py").read_bytes()
        assert oct(folder.parent.parent.stat().st_mode & 0o777) == "0o700"
        recorded = {"files": [f"{folder}/weights.bin"], "error": f"in {folder}/mine.py"}
        assert restored(recorded, bundle, folder) == {
            "files": [str(tmp_path / "p" / "weights.bin")],
            "error": f"in {tmp_path / 'p' / 'mine.py'}",
        }
    assert not folder.exists()  # nothing a policy wrote there lasts to the next chunk
    forged = replace(bundle, files=(("mine.py", b"other", bundle.files[0][2]), *bundle.files[1:]))
    with pytest.raises(ValueError, match="mine.py of .*: its SHA-256 on this worker is not the driver's"):
        with unpacked(forged):
            pass
    escaping = replace(bundle, files=(("../x.py", b"x", hashlib.sha256(b"x").hexdigest()),))
    with pytest.raises(ValueError, match="leaves the folder it is sent in"):
        with unpacked(escaping):
            pass
    assert bundle_for(parse_method("nearest")) is None and len(bundle.digest) == 64


def test_an_amat_model_file_plays_from_the_copy_sent(tmp_path):
    method = parse_method("amat:task1")
    bundle = bundle_for(method)
    with unpacked(bundle) as folder:
        there = played_from(bundle, method, folder)
        assert there.target == str(folder / bundle.entry) and Path(there.target).is_file()


def test_a_package_policy_travels_by_content_and_plays_from_the_copy(tmp_path, monkeypatch):
    import shutil
    import sys

    from catmip_rl.benchmark.jobs import Chunk, play_chunk

    pkg = tmp_path / "src" / "shippedpol"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "policy.py").write_text(
        "class First:\n    deterministic = True\n\n    def act(self, engine):\n"
        "        return engine.masks.argmax(-1)\n\n\ndef make_policy(cfg, seed):\n    return First()\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path / "src"))
    method = parse_method("mine=py:shippedpol.policy:make_policy")
    bundle = bundle_for(method)
    assert sorted(rel for rel, _, _ in bundle.files) == ["shippedpol/__init__.py", "shippedpol/policy.py"]
    shutil.rmtree(tmp_path / "src")  # the driver's copy is gone: the chunk plays from what was sent
    path_before = list(sys.path)
    job = Job(method, EvalSetting("task2"), 2, 1000, str(tmp_path / "out"), sampled=False)
    played, machine = play_chunk(Chunk(job, 0, 2, bundle))
    assert played.records.rescue_tick.shape == (2,) and machine["host"]
    assert sys.path == path_before


def test_an_entry_names_the_machine_that_played_it_and_refuses_mixed_cpus():
    from catmip_rl.benchmark.entry import machine_of

    here = {"python": "3.11", "cpu": "x86_64", "cpu_capability": "AVX2", "native_bf16": False}
    assert machine_of([here | {"host": "node-1"}, here | {"host": "node-2"}]) == here
    mixed = [here | {"host": "a"}, here | {"host": "b", "cpu_capability": "AVX512", "native_bf16": True}]
    with pytest.raises(ValueError, match="played on CPUs of different capability"):
        machine_of(mixed)
    with pytest.raises(ValueError, match="^the runs were replayed on CPUs of different capability"):
        machine_of(mixed, "the runs were replayed")  # a board's check refuses them alike
