"""The ``catmip`` CLI and bad input: every bad flag, path or checkpoint gets one line on stderr naming it
and exit code 2, before any work starts, and nothing is written or overwritten without ``--force``."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

import catmip_rl
import catmip_rl.benchmark.leaderboard
import catmip_rl.benchmark.paper
import catmip_rl.benchmark.suite
import catmip_rl.evaluation.evaluate
import catmip_rl.training.collect
import catmip_rl.training.train
from catmip_env.envs.search_rescue_v0 import SearchRescueEnv
from catmip_rl.cli.args import CPUS
from catmip_rl.cli.main import main
from catmip_rl.cli.parser import DEFAULT_PRESET, build_parser
from catmip_rl.store.checkpoint import SHIPPED_DIR, resume_checkpoint
from catmip_rl.store.files import open_csv_log
from catmip_rl.store.model_files import CheckpointError, read_checkpoint
from catmip_rl.training.presets import TRAIN_PRESETS, make_train_config

SHIPPED = SHIPPED_DIR / "amat_task1.pt"


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    """Bad checkpoints of every kind, a non-empty folder, an existing file, a training run whose
    latest.pt is truncated (iter_000001.pt readable, iter_000002.pt not), one whose checkpoints are all
    unreadable, symbolic links to nothing (``dangling``, ``dangling.gif``), a model file whose state
    dict does not fit its config."""
    d = tmp_path_factory.mktemp("cli")
    out = {
        "random": d / "random.pt",
        "text": d / "text.pt",
        "truncated": d / "truncated.pt",
        "empty": d / "empty.pt",
        "nonempty": d / "nonempty",
        "file": d / "file.txt",
        "run": d / "run",
        "dangling": d / "dangling",
        "badsd": d / "badsd.pt",
        "corrupt_run": d / "corrupt_run",
    }
    out["random"].write_bytes(os.urandom(4096))
    out["text"].write_text("not a checkpoint\n")
    out["truncated"].write_bytes(SHIPPED.read_bytes()[:20_000])
    out["empty"].write_bytes(b"")
    out["nonempty"].mkdir()
    (out["nonempty"] / "keep.txt").write_text("precious")
    (out["nonempty"] / "old.gif").write_bytes(b"GIF89a precious")
    out["file"].write_text("precious")
    ckpts = out["run"] / "checkpoints"
    ckpts.mkdir(parents=True)
    torch.save(_training_checkpoint(1), ckpts / "iter_000001.pt")
    (ckpts / "iter_000002.pt").write_bytes(b"junk")
    (ckpts / "latest.pt").write_bytes((ckpts / "iter_000001.pt").read_bytes()[:3000])
    out["dangling"].symlink_to(d / "nowhere")
    (d / "dangling.gif").symlink_to(d / "nowhere.gif")
    blob = read_checkpoint(SHIPPED)
    torch.save(blob | {"state_dict": {"x": torch.zeros(1)}}, out["badsd"])  # every key missing
    (out["corrupt_run"] / "checkpoints").mkdir(parents=True)
    for name in ("latest.pt", "iter_000001.pt", "iter_000002.pt"):
        (out["corrupt_run"] / "checkpoints" / name).write_bytes(b"junk")
    return out


def _training_checkpoint(iteration: int, **config) -> dict:
    """The keys ``--resume`` reads (store.checkpoint.save_training_checkpoint), with a tiny config."""
    cfg = make_train_config("tiny", **config)
    return {"iteration": iteration, "episodes": 8, "model": {}, "optimizer": {}, "value_norm": {},
            "generator": torch.Generator().get_state(), "torch_rng": torch.get_rng_state(),
            "config": cfg.to_json()}  # fmt: skip


def _fails(capsys, argv: list[str], *needles: str) -> str:
    """Run ``catmip argv`` in-process: exit code 2, one line on stderr holding every needle."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err and "weights_only" not in err
    for needle in needles:
        assert needle in err, (needle, err)
    return err


# -- corrupted checkpoints -------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["random", "text", "truncated", "empty"])
@pytest.mark.parametrize("command", ["eval", "render", "bench"])
def test_a_corrupted_checkpoint_is_refused_naming_it_before_any_work(files, tmp_path, capsys, kind, command):
    bad = files[kind]
    argv = {
        "eval": ["eval", "--method", f"amat:{bad}", "--episodes", "1", "--out", str(tmp_path / "out")],
        "render": ["render", "--method", f"amat:{bad}", "--out", str(tmp_path / "out" / "ep.gif")],
        "bench": ["bench", "paper", "--figure", "6", "--methods", "nearest", "--method", f"amat:{bad}",
                  "--episodes", "1", "--jobs", "1", "--out", str(tmp_path / "out")],
    }[command]  # fmt: skip
    _fails(capsys, argv, str(bad), "not a readable checkpoint")
    assert not (tmp_path / "out").exists()


def test_train_resume_from_a_corrupted_latest_names_the_newest_readable_checkpoint(files, capsys):
    run = files["run"]
    err = _fails(capsys, ["train", "--run-dir", str(run), "--resume"], "latest.pt", "truncated")
    assert f"newest readable checkpoint is {run / 'checkpoints' / 'iter_000001.pt'} (iteration 1)" in err
    assert "copy it over" in err
    with pytest.raises(CheckpointError, match="iter_000001"):
        resume_checkpoint(run)


def test_resume_without_a_preset_continues_with_the_runs_own_config(tmp_path, monkeypatch):
    (tmp_path / "run" / "checkpoints").mkdir(parents=True)
    torch.save(_training_checkpoint(3, iterations=7), tmp_path / "run" / "checkpoints" / "latest.pt")
    seen = {}
    monkeypatch.setattr(
        catmip_rl.training.train, "train", lambda cfg, run_dir, **kw: seen.update(cfg=cfg, **kw)
    )
    assert main(["train", "--run-dir", str(tmp_path / "run"), "--resume", "--epochs", "3"]) == 0
    assert seen["cfg"] == make_train_config("tiny", iterations=7, epochs=3) and seen["resume"]
    assert main(["train", "--run-dir", str(tmp_path / "new")]) == 0
    assert seen["cfg"] == make_train_config(DEFAULT_PRESET) and DEFAULT_PRESET != "paper"


def test_resuming_a_complete_run_says_so_and_trains_nothing(tmp_path, monkeypatch, capsys):
    (tmp_path / "run" / "checkpoints").mkdir(parents=True)
    torch.save(_training_checkpoint(7, iterations=7), tmp_path / "run" / "checkpoints" / "latest.pt")
    seen = {}
    monkeypatch.setattr(catmip_rl.training.train, "train", lambda cfg, run_dir, **kw: seen.update(cfg=cfg))
    assert main(["train", "--run-dir", str(tmp_path / "run"), "--resume"]) == 0
    out = capsys.readouterr().out
    assert "is complete (iteration 7 of 7): nothing trained" in out and "--iterations" in out
    assert "run written" not in out and seen["cfg"].optim.iterations == 7  # train checked the run, as ever
    assert main(["train", "--run-dir", str(tmp_path / "run"), "--resume", "--iterations", "9"]) == 0
    assert seen["cfg"].optim.iterations == 9 and "run written" in capsys.readouterr().out


# -- flags, outputs, refusals (table) ---------------------------------------------------------------------
EVAL = ["eval", "--method", "nearest", "--episodes", "1"]
RENDER = ["render", "--method", "nearest"]
BENCH = ["bench", "paper", "--figure", "6", "--methods", "nearest", "--episodes", "1", "--jobs", "1"]
TRAIN = ["train", "--preset", "tiny"]
SUITE = ["bench", "suite", "--method", "nearest", "--episodes", "1", "--jobs", "1"]


def _set(item: str) -> list[str]:
    return [*TRAIN, "--set", item, "--run-dir", "{out}"]


# (argv with {out} / {nonempty} / {file} / {run} placeholders, words the one line must hold)
CASES = {
    "eval --threads 0": ([*EVAL, "--threads", "0", "--out", "{out}"], ["--threads", "int from 1"]),
    "eval --threads > CPUs": ([*EVAL, "--threads", "{cpus1}", "--out", "{out}"], ["--threads", "CPU count"]),
    "eval --comm inf": ([*EVAL, "--comm", "inf", "--out", "{out}"], ["--comm", "finite"]),
    "eval --out a dangling link": ([*EVAL, "--out", "{dangling}"], ["--out", "symbolic link", "nowhere"]),
    "eval --out under a dangling link": ([*EVAL, "--out", "{dangling}/sub"], ["symbolic link"]),
    "eval a folder without a model": (["eval", "--method", "amat:{nonempty}", "--out", "{out}"],
                                      ["no AMAT checkpoint in the folder", "a .pt file"]),
    "eval amat: state dict does not fit": (["eval", "--method", "amat:{badsd}", "--out", "{out}"],
                                           ["does not fit", "missing keys", "in all)", "unexpected keys: x"]),
    "eval --episodes 0": ([*EVAL, "--episodes", "0", "--out", "{out}"], ["--episodes"]),
    "eval --seed -1": ([*EVAL, "--seed", "-1", "--out", "{out}"], ["--seed", "int >= 0"]),
    "eval --noise 1": ([*EVAL, "--noise", "1", "--out", "{out}"], ["--noise"]),
    "eval --noise nan": ([*EVAL, "--noise", "nan", "--out", "{out}"], ["--noise"]),
    "eval --comm 0": ([*EVAL, "--comm", "0", "--out", "{out}"], ["--comm", "positive"]),
    "eval --comm 1e-300": ([*EVAL, "--comm", "1e-300", "--out", "{out}"],
                           ["--comm", "sigma >= 0.01", "'1e-300'"]),
    "eval --max-ma-ticks 0": ([*EVAL, "--max-ma-ticks", "0", "--out", "{out}"], ["--max-ma-ticks"]),
    "eval --max-ma-ticks huge": ([*EVAL, "--task", "task2", "--max-ma-ticks", "9999999999", "--out", "{out}"],
                                 ["--max-ma-ticks 9999999999", "int in [1, 400] (task2's horizon)"]),
    "eval --max-ma-ticks past int64": ([*EVAL, "--max-ma-ticks", str(10**20), "--out", "{out}"],
                                       ["--max-ma-ticks", "[1, 300] (task1's horizon)"]),
    "render --max-ma-ticks huge": ([*RENDER, "--max-ma-ticks", "10000000000", "--out", "{out}.gif"],
                                   ["--max-ma-ticks", "horizon"]),
    "eval --task 9": ([*EVAL, "--task", "task9", "--out", "{out}"], ["--task", "invalid choice"]),
    "eval unknown method": (["eval", "--method", "dijkstra", "--out", "{out}"], ["--method", "unknown"]),
    "eval missing model": (["eval", "--method", "amat:nope", "--out", "{out}"], ["'nope' does not", "task1"]),
    "eval --out a file": ([*EVAL, "--out", "{file}"], ["--out", "is a file"]),
    "eval --out not empty": ([*EVAL, "--out", "{nonempty}"], ["--out", "not empty", "--force"]),
    "eval --out a run dir": ([*EVAL, "--out", "{run}"], ["not empty", "checkpoints"]),
    "eval --out under a file": ([*EVAL, "--out", "{file}/sub"], ["is a file"]),
    "render --fps 0": ([*RENDER, "--fps", "0", "--out", "{out}.gif"], ["--fps", "int >= 1"]),
    "render --episode -1": ([*RENDER, "--episode", "-1", "--out", "{out}.gif"], ["--episode"]),
    "render --out a folder": ([*RENDER, "--out", "{nonempty}"], ["--out", "is a folder"]),
    "render --out png": ([*RENDER, "--out", "{out}.png"], ["--out", ".gif"]),
    "render --out existing": ([*RENDER, "--out", "{nonempty}/old.gif"], ["exists", "--force"]),
    "render --out a dangling link": ([*RENDER, "--out", "{dangling}.gif"], ["exists", "symbolic link"]),
    "bench --episodes -1": ([*BENCH, "--episodes", "-1", "--out", "{out}"], ["--episodes", "int >= 1"]),
    "bench --seed -1": ([*BENCH, "--seed", "-1", "--out", "{out}"], ["--seed", "int >= 0"]),
    "bench --jobs 0": ([*BENCH, "--jobs", "0", "--out", "{out}"], ["--jobs"]),
    "bench --figure 5": ([*BENCH, "--figure", "5", "--out", "{out}"], ["--figure", "invalid choice"]),
    "bench no figure": (["bench", "paper", "--out", "{out}"], ["--figure N or --all"]),
    "bench bad methods": ([*BENCH, "--methods", "nearest,astar", "--out", "{out}"], ["--methods", "astar"]),
    "bench --methods ,": ([*BENCH, "--methods", ",", "--out", "{out}"], ["--methods", "comma list"]),
    "bench --method =M": ([*BENCH, "--method", "=amat:task1", "--out", "{out}"], ["--method", "empty name"]),
    "bench --jobs > CPUs": ([*BENCH, "--jobs", "{cpus1}", "--out", "{out}"], ["--jobs", "CPU count"]),
    "bench --threads > CPUs": ([*BENCH, "--threads", "{cpus1}", "--out", "{out}"],
                               ["--threads", "CPU count"]),
    "bench jobs x threads > CPUs": ([*BENCH, "--jobs", "{cpus}", "--threads", "{cpus}", "--out", "{out}"],
                                    ["--jobs", "x --threads", "more than this machine"]),
    "bench perf --figure": (["bench", "perf", "--figure", "6"], ["bench perf: error", "--figure"]),
    "bench perf --episodes": (["bench", "perf", "--episodes", "1"], ["bench perf: error", "--episodes"]),
    "bench fig dir not empty": ([*BENCH, "--out", "{figs}"], ["fig6 is not empty", "--force"]),
    # what the leaderboard would refuse in the entry is refused before the suite plays
    "bench suite --notes control": ([*SUITE, "--notes", "nearest=a\x1b[2Jb", "--out", "{out}"],
                                    ["--notes nearest=...: notes holds a control character", "would refuse"]),
    "bench suite --code scheme": ([*SUITE, "--code", "nearest=javascript:alert(1)", "--out", "{out}"],
                                  ["--code nearest=...", "neither an http(s) address nor a relative path"]),
    "bench suite --notes long": ([*SUITE, "--notes", "nearest=" + "x" * 1001, "--out", "{out}"],
                                 ["notes is 1,001 characters, at most 1,000"]),
    "bench suite long name": (["bench", "suite", "--method", "n" * 65 + "=nearest", "--out", "{out}"],
                              ["--method NAME: method is 65 characters, at most 64"]),
    "train --iterations 0": ([*TRAIN, "--iterations", "0", "--run-dir", "{out}"], ["--iterations"]),
    "train --lr -1": ([*TRAIN, "--lr", "-1", "--run-dir", "{out}"], ["--lr", "> 0"]),
    "train --lr inf": ([*TRAIN, "--lr", "inf", "--run-dir", "{out}"], ["--lr"]),
    "train --minutes x": ([*TRAIN, "--minutes", "x", "--run-dir", "{out}"], ["--minutes"]),
    "train --device tpu": ([*TRAIN, "--device", "tpu", "--run-dir", "{out}"], ["--device"]),
    "train --set no =": ([*TRAIN, "--set", "gamma", "--run-dir", "{out}"], ["--set", "FIELD=VALUE"]),
    "train --set bad value": ([*TRAIN, "--set", "gamma=2", "--run-dir", "{out}"], ["bad config", "gamma"]),
    "train --set bad shape": (_set("amat=5"), ["bad config", "TrainConfig.amat", "got 5"]),
    "train --set unknown": ([*TRAIN, "--set", "foo=1", "--run-dir", "{out}"], ["unknown TrainConfig field"]),
    "train --set seed=1.5": (_set("seed=1.5"), ["TrainConfig.seed", "int"]),
    "train --set eval_seed=1.5": (_set("eval_seed=1.5"), ["TrainConfig.eval_seed must be an int >= 0"]),
    "train --set seed=2**64": (_set(f"seed={2**64}"), ["seed", "2**64"]),
    "train --set iterations=true": (_set("iterations=true"), ["TrainConfig.iterations must be", "got True"]),
    "train --set warm_start_heading=1": (_set("warm_start_heading=1"),
                                        ["TrainConfig.warm_start_heading must be true or false", "got 1"]),
    "train --set lr=Infinity": (_set("lr=Infinity"), ["TrainConfig.lr", "finite"]),
    "train --set entropy_coef=NaN": (_set("entropy_coef=NaN"), ["TrainConfig.entropy_coef", "finite"]),
    "train --set amat=null": (_set("amat=null"), ["TrainConfig.amat", "JSON object"]),
    "train --set amat bool": (_set('amat={{"embed_dim": true}}'), ["AmatConfig.embed_dim", "int"]),
    "train --set env layout list": (_set('env_overrides={{"layout": ["#####", "#...#", "#####"]}}'),
                                    ["EnvConfig.layout", "one string"]),
    "train --set env team str": (_set('env_overrides={{"team": "rescuer"}}'),
                                 ["EnvConfig.team must be a list of class names, got 'rescuer'"]),
    "train --set env comm str": (_set('env_overrides={{"comm_sigma": "abc"}}'), ["comm_sigma", "finite"]),
    "train --set env sync str": (_set('env_overrides={{"synchronous": "yes"}}'), ["EnvConfig.synchronous"]),
    "train --set env classes": (_set('env_overrides={{"classes": [5]}}'), ["EnvConfig: classes"]),
    "train --set env map_size": (_set('env_overrides={{"map_size": 100000}}'), ["map_size", "[10, 512]"]),
    "train --set env comm choices": (_set('env_overrides={{"comm_sigma_choices": [4, 0]}}'),
                                     ["EnvConfig.comm_sigma_choices", ">= 0.01", "got (4, 0)"]),
    "train --set env comm tiny": (_set('env_overrides={{"comm_sigma": 1e-300}}'),
                                  ["EnvConfig.comm_sigma", ">= 0.01", "got 1e-300"]),
    "train --init-from missing": ([*TRAIN, "--init-from", "nope", "--run-dir", "{out}"],
                                  ["'nope' does not exist", "shipped"]),
    "train --init-from corrupt": ([*TRAIN, "--init-from", "{file}", "--run-dir", "{out}"],
                                  ["is not a readable checkpoint"]),
    "train --init-from another model": ([*TRAIN, "--init-from", "task1", "--run-dir", "{out}"],
                                        ["init_from 'task1' is an AMAT of another configuration"]),
    "train --threads > CPUs": ([*TRAIN, "--threads", "{cpus1}", "--run-dir", "{out}"], ["--threads", "CPU"]),
    "train --update-processes > CPUs": ([*TRAIN, "--update-processes", "{cpus1}", "--run-dir", "{out}"],
                                        ["--update-processes", "CPU count"]),
    "train --set threads > CPUs": (_set("threads={cpus1}"), ["threads = ", f"{CPUS} CPUs"]),
    "train --run-dir a dangling link": ([*TRAIN, "--run-dir", "{dangling}"], ["run dir", "symbolic link"]),
    "train --preset bad": (["train", "--preset", "huge", "--run-dir", "{out}"], ["--preset", "invalid"]),
    "train into a non-empty dir": ([*TRAIN, "--run-dir", "{nonempty}"], ["not empty"]),
    "train into a run": ([*TRAIN, "--run-dir", "{run}"], ["already holds a run", "--resume"]),
    "train --resume nothing": ([*TRAIN, "--run-dir", "{out}", "--resume"], ["no checkpoint at"]),
    "train --resume all corrupt": ([*TRAIN, "--run-dir", "{corrupt_run}", "--resume"],
                                   ["latest.pt", "no checkpoints/iter_*.pt is readable either (2 tried)"]),
    "export a model file": (["export", "task1", "--out", "{out}.pt"], ["not a training checkpoint"]),
    "export a missing run": (["export", "{out}/nope", "--out", "{out}.pt"], ["does not exist"]),
    "export a corrupt run": (["export", "{corrupt_run}", "--out", "{out}.pt"], ["not a readable checkpoint"]),
    "export --out not .pt": (["export", "task1", "--out", "{out}.txt"], ["--out", "must end in .pt"]),
    "export --out a folder": (["export", "task1", "--out", "{nonempty}"], ["--out", "is a folder"]),
    "export --out exists": (["export", "task1", "--out", "{badsd}"], ["--out", "exists", "--force"]),
    "no command": ([], ["required"]),
}  # fmt: skip


@pytest.mark.parametrize("case", list(CASES))
def test_bad_input_gets_one_line_and_exit_code_2_before_any_work(case, files, tmp_path, capsys):
    (tmp_path / "figs" / "fig6").mkdir(parents=True)
    (tmp_path / "figs" / "fig6" / "summary.csv").write_text("precious")
    where = {k: files[k] for k in ("nonempty", "file", "run", "dangling", "badsd", "corrupt_run")} | {
        "out": tmp_path / "out",
        "figs": tmp_path / "figs",
        "cpus1": CPUS + 1,
        "cpus": CPUS,
    }
    argv, needles = CASES[case]
    before = {p: p.read_bytes() for p in [*files["nonempty"].iterdir(), files["file"]]}
    _fails(capsys, [a.format(**where) for a in argv], *needles)
    assert not (tmp_path / "out").exists() and not list(tmp_path.glob("out*"))  # nothing written
    assert not list(files["nonempty"].parent.glob("*.tmp*"))  # no stray temporary file
    assert {p: p.read_bytes() for p in before} == before  # nothing overwritten
    assert (tmp_path / "figs" / "fig6" / "summary.csv").read_text() == "precious"


def test_a_refused_training_run_leaves_no_run_dir(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # as if the distributed extra were missing
    _fails(capsys, [*TRAIN, "--collector", "ray", "--ray-workers", "2", "--run-dir", str(tmp_path / "r")],
           "catmip[distributed]")  # fmt: skip
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    _fails(capsys, [*TRAIN, "--device", "cuda", "--run-dir", str(tmp_path / "r")], "no CUDA device")
    assert not (tmp_path / "r").exists()


# -- a run stopped before its first checkpoint leaves its run dir as it found it --------------------------
TINY_RUN = [*TRAIN, "--set", "iterations=1", "--no-progress"]


def _raises(err: BaseException):
    def stop(*args, **kwargs):
        raise err

    return stop


def _warm_start_then(err: BaseException):
    """A warm start that opens its log (warm_start.csv), then stops with ``err`` (Ctrl-C, say)."""

    def warm_start(cfg, model, collector, gen, run_dir, *args, **kwargs):
        f, _ = open_csv_log(run_dir / "warm_start.csv", ["round"], None, key="round")
        f.close()
        raise err

    return warm_start


def _accepts_a_new_run(run_dir: Path, monkeypatch) -> bool:
    """``catmip train --run-dir run_dir`` gets past every check (to building the model)."""
    with monkeypatch.context() as m:
        m.setattr(catmip_rl.training.train, "make_model", _work_started)
        with pytest.raises(_WorkStarted):
            main([*TINY_RUN, "--run-dir", str(run_dir)])
    return True


@pytest.mark.parametrize("where", ["new", "nested", "empty"])
@pytest.mark.parametrize(
    "when, error, code, needle",
    [
        ("collect", (KeyboardInterrupt,), 130, "interrupted; stopped before its first checkpoint"),
        ("collect", (ValueError, "bad episode"), 2, "bad episode; stopped before its first checkpoint"),
        ("collect", (MemoryError, "Unable to allocate 74 TiB"), 2, "out of memory (Unable to allocate 74"),
        ("warm start", (KeyboardInterrupt,), 130, "interrupted; stopped before its first checkpoint"),
    ],
)  # fmt: skip
def test_a_run_stopped_before_its_first_checkpoint_removes_what_it_wrote(
    tmp_path, capsys, monkeypatch, where, when, error, code, needle
):
    run = {"new": tmp_path / "run", "nested": tmp_path / "a" / "b" / "run", "empty": tmp_path / "run"}[where]
    if where == "empty":
        run.mkdir()
    kind, *message = error
    threads = torch.get_num_threads()
    with monkeypatch.context() as m:
        if (
            when == "collect"
        ):  # the first iteration's collection fails (config.json, logs, tensorboard/ written)
            m.setattr(catmip_rl.training.collect.Collector, "collect", _raises(kind(*message)))
            argv = [*TINY_RUN, "--run-dir", str(run)]
        else:  # Ctrl-C during the warm start, after its log was opened
            m.setattr(catmip_rl.training.train, "warm_start", _warm_start_then(kind(*message)))
            argv = [*TINY_RUN, "--warm-start", "nearest", "--run-dir", str(run)]
        try:
            assert main(argv) == code
        finally:
            torch.set_num_threads(threads)
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and needle in err, err
    assert f"{run} was {'emptied' if where == 'empty' else 'removed'}" in err
    assert list(tmp_path.iterdir()) == ([run] if where == "empty" else [])  # nothing else left behind
    assert where != "empty" or not list(run.iterdir())
    assert _accepts_a_new_run(run, monkeypatch)


def test_an_unexpected_error_removes_the_run_too_and_says_so_in_a_note(tmp_path, monkeypatch):
    threads = torch.get_num_threads()
    with monkeypatch.context() as m:
        m.setattr(catmip_rl.training.collect.Collector, "collect", _raises(RuntimeError("a bug")))
        try:
            with pytest.raises(RuntimeError, match="a bug") as info:
                main([*TINY_RUN, "--run-dir", str(tmp_path / "run")])
        finally:
            torch.set_num_threads(threads)
    assert "stopped before its first checkpoint" in info.value.__notes__[0]
    assert not (tmp_path / "run").exists()


def test_a_run_stopped_after_a_checkpoint_keeps_everything_for_resume(tmp_path, capsys, monkeypatch):
    """The warm start's checkpoint (iter_000000.pt) is written; Ctrl-C in the first PPO iteration."""
    run = tmp_path / "run"
    threads = torch.get_num_threads()
    with monkeypatch.context() as m:
        m.setattr(catmip_rl.training.train, "warm_start", lambda *args, **kwargs: (0.0, 0))  # no rounds
        m.setattr(catmip_rl.training.collect.Collector, "collect", _raises(KeyboardInterrupt()))
        try:
            assert main([*TINY_RUN, "--warm-start", "nearest", "--run-dir", str(run)]) == 130
        finally:
            torch.set_num_threads(threads)
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "interrupted; its checkpoints are kept" in err, err
    assert f"catmip train --run-dir {run} --resume" in err
    assert {p.name for p in run.iterdir()} >= {"config.json", "metrics.csv", "checkpoints"}
    assert resume_checkpoint(run)["iteration"] == 0
    with monkeypatch.context() as m:  # and --resume accepts it
        m.setattr(catmip_rl.training.train, "make_model", _work_started)
        with pytest.raises(_WorkStarted):
            main(["train", "--run-dir", str(run), "--resume", "--no-progress"])


def test_force_writes_into_a_non_empty_folder_and_keeps_other_files(tmp_path, capsys):
    out = tmp_path / "eval"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    assert main([*EVAL, "--out", str(out), "--no-progress", "--threads", "1", "--force"]) == 0
    assert (out / "summary.json").exists() and (out / "notes.txt").read_text() == "mine"


def test_eval_prints_the_standard_error_of_success_by_tick_100(tmp_path, capsys):
    out = tmp_path / "eval"
    assert (
        main(["eval", "--method", "random-rescue", "--episodes", "8", "--out", str(out), "--no-progress"])
        == 0
    )
    p = json.loads((out / "summary.json").read_text())["success_by_100"]
    assert f"by tick 100 {p:.2f} (standard error {(p * (1 - p) / 8) ** 0.5:.3f})" in capsys.readouterr().out


def test_render_defaults_to_the_envs_fps_and_overwrites_only_with_force(tmp_path, capsys):
    args = build_parser().parse_args([*RENDER, "--out", "x.gif"])
    assert args.fps == SearchRescueEnv.metadata["render_fps"]
    gif = tmp_path / "ep.gif"
    gif.write_bytes(b"old")
    assert main([*RENDER, "--out", str(gif), "--threads", "1", "--force"]) == 0
    pil = pytest.importorskip("PIL.Image")
    with pil.open(gif) as im:  # GIF stores centiseconds: 1000 / 8 ms -> 120 ms
        assert im.info["duration"] == 10 * round(100 / SearchRescueEnv.metadata["render_fps"])
    assert not list(tmp_path.glob(".*tmp*"))


# -- shipped models, version, help ------------------------------------------------------------------------
def test_version(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"catmip {catmip_rl.__version__}"


def test_every_flag_has_help_and_train_defaults_to_a_short_preset(capsys):
    def walk(parser: argparse.ArgumentParser):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub in action.choices.values():
                    yield from walk(sub)
            else:
                yield parser.prog, action

    def parsers(parser: argparse.ArgumentParser):
        yield parser
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub in action.choices.values():
                    yield from parsers(sub)

    missing = [(prog, a.dest) for prog, a in walk(build_parser()) if not a.help]
    assert not missing
    assert [p.prog for p in parsers(build_parser()) if not p.description] == []
    assert main(["train", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert f"default {DEFAULT_PRESET}" in text and "62,500 iterations" in text
    preset = TRAIN_PRESETS[DEFAULT_PRESET]  # each override flag shows the default preset's value
    optim = preset.optim
    for flag, value in (("--iterations", optim.iterations), ("--epochs", optim.epochs),
                        ("--lr", optim.lr), ("--warm-start", preset.imitation.warm_start),
                        ("--minutes", optim.budget_minutes)):  # fmt: skip
        shown = text[text.index(f"{flag} ", text.index("overrides of the preset")) :]
        assert f"({DEFAULT_PRESET}: {value})" in shown[: shown.index(" --", 3)], flag
    assert main(["eval", "--help"]) == 0
    text = capsys.readouterr().out
    assert "(default: 100)" in text and "the paper uses 5, 10, 20" in " ".join(text.split())
    assert main(["bench", "perf", "--help"]) == 0
    text = capsys.readouterr().out
    assert "--quick" in text and "--figure" not in text and "--episodes" not in text


def test_a_state_dict_that_does_not_fit_is_summed_up_in_a_short_line(files, tmp_path, capsys):
    err = _fails(capsys, ["eval", "--method", f"amat:{files['badsd']}", "--out", str(tmp_path / "out")])
    assert "missing keys: global_conv.weight, global_conv.bias, global_ln.weight, ... (" in err
    assert len(err) < 400, len(err)


# -- through the installed entry point: no traceback reaches the user ------------------------------------
def _catmip() -> list[str]:
    script = Path(sys.executable).with_name("catmip")
    return [str(script)] if script.exists() else [sys.executable, "-m", "catmip_rl.cli"]


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["eval", "--method", "amat:{random}", "--out", "{out}"], "not a readable checkpoint"),
        (["render", "--method", "nearest", "--fps", "0", "--out", "{out}.gif"], "argument --fps"),
        (["train", "--preset", "tiny", "--run-dir", "{run}", "--resume"], "iter_000001.pt"),
    ],
)
def test_the_command_prints_one_line_and_exits_2(argv, needle, files, tmp_path):
    where = {"random": files["random"], "out": tmp_path / "out", "run": files["run"]}
    argv = [a.format(**where) for a in argv]
    proc = subprocess.run([*_catmip(), *argv], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and needle in proc.stderr, proc.stderr


# -- fuzz: random argument lists never raise ------------------------------------------------------------
class _WorkStarted(Exception):
    """Raised by the stubs standing in for the first real work: the input was accepted."""


def _work_started(*args, **kwargs):
    raise _WorkStarted


# per flag, values it accepts (often: the fuzz must also reach past argparse) ...
_INT, _METHOD = (
    ["0", "1", "2", "3"],
    ["nearest", "window:rrt", "amat:task1", "b=amat-guard:task1", "amat:{run}"],
)
_SETTING = {"--method": _METHOD, "--task": ["task1", "task3"], "--comm": ["full", "4", "2.5"],
            "--noise": ["0", "0.05"], "--max-ma-ticks": ["5", "20"], "--seed": _INT, "--threads": ["1", "2"],
            "--force": []}  # fmt: skip
FLAGS = {
    "train": {"--preset": ["tiny", "small", "paper"], "--run-dir": ["{new}", "{nonempty}", "{run}"],
              "--iterations": _INT, "--num-worlds": ["2", "4"], "--epochs": _INT, "--minibatches": _INT,
              "--micro-batch": _INT, "--lr": ["0.001", "1"], "--seed": _INT, "--device": ["cpu", "cuda"],
              "--threads": ["1", "2"], "--update-processes": ["1", "2"], "--warm-start": ["nearest", "a*"],
              "--init-from": ["task1", "{run}", "nope"],
              "--target-kl": ["0", "0.01"], "--precision": ["fp32", "auto"], "--minutes": ["0", "0.5"],
              "--eval-every": _INT, "--eval-episodes": _INT, "--checkpoint-every": _INT,
              "--collector": ["local", "ray"], "--ray-workers": ["1", "2"], "--ray-address": ["auto", ""],
              "--set": ["gamma=0.9", "amat={{}}", "env_overrides={{}}", "amat={{\"embed_dim\": 8}}", "seed=3",
                        "eval_seed=7", "env_overrides={{\"comm_sigma\": 4}}"],
              "--resume": []},
    "eval": _SETTING | {"--episodes": ["1", "2"], "--out": ["{new}", "{nonempty}"]},
    "render": _SETTING | {"--episode": _INT, "--fps": ["8"], "--out": ["{new}.gif", "{nonempty}/old.gif"]},
    "bench paper": {"--figure": ["6", "11"], "--all": [], "--methods": ["nearest,rrt", "a=amat:task1,apf"],
                    "--method": _METHOD, "--episodes": ["1"], "--seed": _INT, "--jobs": ["1", "2"],
                    "--threads": ["1", "2"], "--out": ["{new}", "{nonempty}"], "--force": []},
    "bench suite": {"--method": _METHOD, "--episodes": ["1", "1001"], "--jobs": ["1", "2"],
                    "--threads": ["1"], "--code": ["nearest=https://x", "x"],
                    "--notes": ["nearest=a note", "=x"], "--out": ["{new}", "{nonempty}"], "--resume": [],
                    "--no-progress": []},
    "leaderboard": {"--entries": ["{new}", "{nonempty}", "{file}"], "--episodes": ["1", "2"],
                    "--out": ["{new}", "{nonempty}"], "--force": []},
    "bench perf": {"--quick": [], "--figure": ["6"], "--episodes": ["1"]},  # the last two: not perf flags
    "export": {"--out": ["{new}.pt", "{badsd}", "{new}"], "--force": []},
}  # fmt: skip
# ... and values no flag should take (most flags)
GARBAGE = ["0", "-1", "0.5", "-0.5", "1e999", "nan", "inf", "", "abc", "-", "--", "cuda:x", "amat:nope",
           "amat:{random}", "amat:{text}", "amat:{truncated}", "amat:{empty}", "x=y", "gamma=2", "amat=5",
           "env_overrides=[1]", "iterations=0", "{file}", "{new}.png", "{file}/sub", "{random}",
           "seed=1.5", "eval_seed=1.5", "iterations=true", "lr=Infinity", "entropy_coef=NaN", "amat=null",
           "env_overrides=null", 'env_overrides={{"layout": ["#"]}}', 'env_overrides={{"team": "rescuer"}}',
           'env_overrides={{"comm_sigma": "abc"}}', 'env_overrides={{"map_size": 100000}}',
           "threads=100000", "update_processes=1000", "100000", "=amat:task1", ",", "{dangling}",
           "{dangling}.gif", "{dangling}/sub", "amat:{badsd}", "amat:{nonempty}",
           "{corrupt_run}"]  # fmt: skip
REQUIRED = {"train": ["--run-dir", "{new}"], "eval": ["--method", "nearest", "--out", "{new}"],
            "render": ["--method", "nearest", "--out", "{new}.gif"],
            "bench paper": ["--figure", "6"], "bench perf": [], "export": ["{run}"],
            "bench suite": ["--method", "nearest", "--out", "{new}"], "leaderboard": []}  # fmt: skip


# ~3 s for the default 300 examples; CATMIP_FUZZ_EXAMPLES=4000 for a longer hunt (~50 s, passed)
@settings(
    max_examples=int(os.environ.get("CATMIP_FUZZ_EXAMPLES", 300)),
    deadline=None,
    suppress_health_check=list(HealthCheck),
)
@given(data=st.data(), command=st.sampled_from(sorted(FLAGS)), required=st.booleans())
def test_fuzz_random_arguments_exit_0_or_2_without_a_traceback(
    files, tmp_path_factory, capsys, monkeypatch, data, command, required
):
    where = {k: str(v) for k, v in files.items()} | {"new": str(tmp_path_factory.mktemp("new") / "x")}
    argv = command.split() + (REQUIRED[command] if required else [])
    for _ in range(data.draw(st.integers(1, 4), label="flags")):
        flag = data.draw(st.sampled_from(sorted(FLAGS[command])), label="flag")
        valid = FLAGS[command][flag]
        if not valid:  # a switch
            argv.append(flag)
            continue
        argv += [flag, data.draw(st.sampled_from(valid) | st.sampled_from(GARBAGE), label=flag)]
    if data.draw(st.integers(0, 9), label="help") == 0:
        argv.append("--help")
    argv = [a.format(**where) for a in argv]
    with monkeypatch.context() as m:  # the first real work of each command raises _WorkStarted
        m.chdir(tmp_path_factory.mktemp("cwd"))  # a value such as "amat:/tmp/x" is a relative path to make
        m.setattr(catmip_rl.evaluation.evaluate, "EventEngine", _work_started)
        m.setattr(catmip_rl.benchmark.paper, "map_jobs", _work_started)
        m.setattr(catmip_rl.benchmark.suite, "map_jobs", _work_started)
        m.setattr(catmip_rl.benchmark.leaderboard, "render_leaderboard", _work_started)
        m.setattr(catmip_rl.training.train, "make_model", _work_started)
        m.setattr(subprocess, "call", _work_started)  # bench perf's benchmarks
        threads = torch.get_num_threads()
        try:
            code = main(argv)
            event(f"{command}: exit {code}")  # --hypothesis-show-statistics shows the mix
        except _WorkStarted:
            code = 0
            event(f"{command}: accepted, work started")
        finally:
            torch.set_num_threads(threads)
    err = capsys.readouterr().err
    assert code in (0, 2), (argv, code, err)
    assert "Traceback" not in err
    if code == 2:
        assert len(err.strip().splitlines()) == 1, (argv, err)


def test_eval_prints_where_the_time_to_the_rescue_goes(tmp_path, capsys):
    out = tmp_path / "eval"
    cmd = ["eval", "--method", "nearest", "--task", "task2", "--comm", "2", "--episodes", "6"]
    assert main([*cmd, "--out", str(out), "--no-progress"]) == 0
    s = json.loads((out / "summary.json").read_text())
    rows = json.loads((out / "episodes.json").read_text())
    informed = [r for r in rows if r["rescued"]]
    want = sum(r["rescue_tick"] - r["rescuer_informed_tick"] for r in informed) / len(informed)
    assert s["mean_informed_to_rescue_ticks"] == pytest.approx(want)
    line = (
        f"a rescuer knew it {s['mean_found_to_informed_ticks']:.1f} ticks later and rescued it "
        f"{s['mean_informed_to_rescue_ticks']:.1f} ticks after that"
    )
    assert line in capsys.readouterr().out


def test_eval_argmax_only_plays_a_learned_policy_once_with_the_same_argmax_numbers(tmp_path, capsys):
    cmd = ["eval", "--method", "amat:task1", "--episodes", "4", "--threads", "1", "--no-progress"]
    assert main([*cmd, "--out", str(tmp_path / "both")]) == 0
    assert main([*cmd, "--argmax-only", "--out", str(tmp_path / "argmax")]) == 0
    both, argmax = (json.loads((tmp_path / d / "summary.json").read_text()) for d in ("both", "argmax"))
    assert both["sampled_pass"] and "sampled_success_rate" in both
    assert not argmax["sampled_pass"]
    assert not {k for k in argmax if k.startswith("sampled_")} - {"sampled_pass"}
    same = {k: v for k, v in both.items() if not k.startswith("sampled_") and k != "seconds"}
    assert same == {k: v for k, v in argmax.items() if not k.startswith("sampled_") and k != "seconds"}
    assert "with sampled actions" not in capsys.readouterr().out.split("amat_task1 (argmax")[-1]


def test_eval_says_when_a_model_plays_with_the_loop_guard(tmp_path, capsys):
    cmd = ["eval", "--method", "amat-guard:task1", "--episodes", "2", "--threads", "1", "--no-progress"]
    assert main([*cmd, "--argmax-only", "--out", str(tmp_path / "guard")]) == 0
    assert "amat_task1-guard (argmax actions, loop guard) on task1" in capsys.readouterr().out


def test_method_help_names_every_planner(capsys, monkeypatch):
    from catmip_env.planners.baselines import PLANNERS

    monkeypatch.setenv("COLUMNS", "100000")  # argparse wraps the help at a hyphen otherwise
    assert main(["eval", "--help"]) == 0
    method = next(line for line in capsys.readouterr().out.splitlines() if "  --method METHOD" in line)
    assert all(f" {name} " in method for name in PLANNERS), method
