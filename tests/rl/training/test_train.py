"""Training: a CLI smoke run, seeded determinism, exact resume, and clear errors."""

import csv
import json
from pathlib import Path

import pytest
import torch

from catmip_rl.cli.main import main as cli
from catmip_rl.store.checkpoint import load_model
from catmip_rl.training.config import TrainConfig
from catmip_rl.training.presets import make_train_config
from catmip_rl.training.run_logs import METRICS
from catmip_rl.training.train import train

RECORDS = Path(__file__).parents[3] / "run-records"
RETIRED = Path(__file__).parents[3] / "docs" / "notes" / "retired-presets.json"


def _params(model):
    return torch.cat([p.detach().flatten() for p in model.parameters()])


def test_cli_tiny_two_iterations(tmp_path):
    # no wall-clock bound here: on a fresh clone the numba kernels compile first (about a minute on
    # 2 cores); speed is measured by benchmarks/, not asserted by tests
    assert cli(["train", "--preset", "tiny", "--run-dir", str(tmp_path / "run"), "--no-progress"]) == 0
    run = tmp_path / "run"
    cfg = TrainConfig.from_json((run / "config.json").read_text())
    assert cfg == make_train_config("tiny")
    rows = list(csv.DictReader((run / "metrics.csv").open()))
    assert [int(r["iteration"]) for r in rows] == [1, 2]
    assert set(rows[0]) == set(METRICS) and rows[1]["eval/success_rate"] != ""
    assert all(float(r["ppo/explained_variance"]) <= 1 for r in rows)  # logged every iteration
    assert (run / "checkpoints" / "latest.pt").exists() and list((run / "tensorboard").iterdir())
    saved = torch.load(run / "checkpoints" / "latest.pt", weights_only=False)
    assert saved["iteration"] == 2 and saved["episodes"] == 16


@pytest.mark.slow
def test_two_seeded_runs_are_identical_and_resume_continues_exactly(tmp_path):
    cfg = make_train_config("tiny", iterations=2, eval_every=0)
    a = train(cfg, tmp_path / "a", progress=False)
    b = train(cfg, tmp_path / "b", progress=False)
    assert torch.equal(_params(a), _params(b))
    # 1 iteration, then resume for the 2nd: same parameters as 2 straight iterations
    half = cfg.replace(iterations=2)
    first = tmp_path / "c"
    train(half.replace(checkpoint_every=1), first, progress=False)  # writes iter 1 and 2
    # rewind: make iter_000001 the latest and resume from it
    ckpts = first / "checkpoints"
    (ckpts / "latest.pt").write_bytes((ckpts / "iter_000001.pt").read_bytes())
    c = train(half, first, resume=True, progress=False)
    assert torch.equal(_params(a), _params(c))
    rows = list(csv.DictReader((first / "metrics.csv").open()))
    assert [int(r["iteration"]) for r in rows] == [1, 2]  # the rewound row 2 was replaced, not duplicated


@pytest.mark.slow
def test_a_run_stopped_between_its_snapshot_and_latest_resumes_with_every_snapshot(tmp_path, monkeypatch):
    from catmip_rl.training import train as train_module

    """latest.pt is written before an iteration's snapshot (a run stopped after its first snapshot
    can always --resume); a run stopped between the two gets the snapshot written again on --resume."""
    cfg = make_train_config("tiny", iterations=2, eval_every=0, checkpoint_every=1)
    run = tmp_path / "r"
    train(cfg, run, progress=False)
    ckpts = run / "checkpoints"
    (ckpts / "iter_000002.pt").unlink()  # stopped while writing it, latest.pt at iteration 2
    train(cfg.replace(iterations=3), run, resume=True, progress=False)
    assert {p.name for p in ckpts.glob("iter_*.pt")} >= {"iter_000001.pt", "iter_000002.pt", "iter_000003.pt"}
    written = []
    real = train_module.Run.save

    def record(self, path):
        written.append(path.name)
        real(self, path)

    monkeypatch.setattr(train_module.Run, "save", record)
    train(cfg.replace(iterations=4), run, resume=True, progress=False)
    assert written.index("latest.pt") < written.index("iter_000004.pt")


def test_errors(tmp_path):
    with pytest.raises(ValueError, match="window"):
        make_train_config("tiny", amat={"embed_dim": 32, "window": 5})
    with pytest.raises(ValueError, match="unknown TrainConfig field"):
        make_train_config("tiny", learning_rate=1.0)
    with pytest.raises(ValueError, match="unknown training preset"):
        make_train_config("huge")
    cfg = make_train_config("tiny", iterations=1, eval_every=0)
    train(cfg, tmp_path / "r", progress=False)
    with pytest.raises(FileExistsError, match="--resume"):
        train(cfg, tmp_path / "r", progress=False)
    with pytest.raises(ValueError, match="another model or task"):
        train(cfg.replace(amat={"embed_dim": 64}), tmp_path / "r", resume=True, progress=False)
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        train(cfg, tmp_path / "empty", resume=True, progress=False)
    assert cli(["train", "--preset", "tiny", "--run-dir", str(tmp_path / "x"), "--set", "gamma=2"]) == 2
    (tmp_path / "file").write_text("")
    with pytest.raises(NotADirectoryError, match="is a file, not a folder"):
        train(cfg, tmp_path / "file", progress=False)
    assert not (tmp_path / "x").exists() and not (tmp_path / "empty").exists()  # refused: nothing left
    assert json.loads(cfg.to_json())["iterations"] == 1


def test_a_time_budget_stops_the_run_and_checkpoints_its_last_iteration(tmp_path):
    cfg = make_train_config("tiny", iterations=50, eval_every=0, checkpoint_every=20, budget_minutes=1e-4)
    train(cfg, tmp_path / "run", progress=False)
    rows = list(csv.DictReader((tmp_path / "run" / "metrics.csv").open()))
    assert len(rows) == 1  # 6 ms of budget: spent by the first iteration
    assert float(rows[0]["time/elapsed_min"]) >= 1e-4 and float(rows[0]["ppo/lr"]) == cfg.optim.lr
    saved = torch.load(tmp_path / "run" / "checkpoints" / "latest.pt", weights_only=False)
    assert saved["iteration"] == 1 and saved["elapsed_s"] >= 6e-3
    epochs = list(csv.DictReader((tmp_path / "run" / "ppo_epochs.csv").open()))
    assert [int(e["epoch"]) for e in epochs] == [1, 2]  # tiny: 2 epochs, no KL target


def test_cli_step_control_warm_start_and_precision_flags(tmp_path, capsys):
    run = tmp_path / "run"
    args = ["train", "--preset", "tiny", "--run-dir", str(run), "--no-progress", "--warm-start", "nearest",
            "--target-kl", "0.02", "--minutes", "5", "--precision", "fp32", "--set", "warm_start_rounds=1",
            "--set", "warm_start_steps=1"]  # fmt: skip
    assert cli(args) == 0
    cfg = TrainConfig.from_json((run / "config.json").read_text())
    assert (cfg.imitation.warm_start, cfg.optim.target_kl, cfg.optim.budget_minutes, cfg.optim.precision) == (
        "nearest",
        0.02,
        5.0,
        "fp32",
    )
    assert (run / "warm_start.csv").exists() and (run / "precision.json").exists()
    bad = ["train", "--preset", "tiny", "--run-dir", str(tmp_path / "bad"), "--warm-start", "dijkstra"]
    assert cli(bad) == 2 and "warm_start" in capsys.readouterr().err
    assert cli(["train", "--preset", "tiny", "--run-dir", str(tmp_path / "b2"), "--target-kl", "-1"]) == 2


@pytest.mark.slow
def test_a_new_run_can_start_from_another_runs_weights(tmp_path):
    from catmip_rl.store.checkpoint import save_model
    from catmip_rl.training.train import build_run

    cfg = make_train_config("tiny", iterations=2, eval_every=0)
    a = train(cfg, tmp_path / "a", progress=False)
    saved = torch.load(tmp_path / "a" / "checkpoints" / "latest.pt", weights_only=True)
    # from a run dir: its latest weights and value normaliser; a fresh optimiser and iteration count
    run = build_run(cfg.replace(init_from=str(tmp_path / "a")))
    assert torch.equal(_params(run.model), _params(a)) and not torch.equal(_params(run.model), _params(
        build_run(cfg).model))  # fmt: skip
    for k, v in saved["value_norm"].items():
        assert torch.equal(run.value_norm.state_dict()[k], v)
    assert float(saved["value_norm"]["debias"]) > 0 and run.iteration == 0 and not run.opt.state
    # from a plain model file: the weights, and a fresh value normaliser (it has none)
    save_model(a, tmp_path / "m.pt")
    run = build_run(cfg.replace(init_from=str(tmp_path / "m.pt")))
    assert torch.equal(_params(run.model), _params(a)) and float(run.value_norm.debias) == 0
    # from an exported model file: its run's value normaliser and clock come along
    assert cli(["export", str(tmp_path / "a"), "--out", str(tmp_path / "e.pt")]) == 0
    run = build_run(cfg.replace(init_from=str(tmp_path / "e.pt")))
    assert torch.equal(_params(run.model), _params(a))
    assert torch.equal(run.value_norm.mean, saved["value_norm"]["mean"])
    assert run.init_source["iteration"] == 2 and run.init_source["elapsed_min"] == saved["elapsed_s"] / 60
    # a fine-tuning run trains from there; resuming it continues its own weights, not init_from's
    ft = cfg.replace(init_from=str(tmp_path / "m.pt"), iterations=1)
    b = train(ft, tmp_path / "b", progress=False)
    written = TrainConfig.from_json((tmp_path / "b" / "config.json").read_text())
    assert written.model.init_from.endswith("m.pt")
    source = json.loads((tmp_path / "b" / "init_from.json").read_text())
    assert source["file"].endswith("m.pt") and source["iteration"] is None  # a model file: no iteration
    assert len(source["sha256"]) == 64
    assert build_run(cfg.replace(init_from=str(tmp_path / "a"))).init_source["iteration"] == 2
    # the clock goes back through every run the weights came from: b started from a's exported file
    tuned = train(cfg.replace(init_from=str(tmp_path / "e.pt"), iterations=1), tmp_path / "t", progress=False)
    assert tuned is not None
    b_saved = torch.load(tmp_path / "t" / "checkpoints" / "latest.pt", weights_only=True)
    chain = build_run(cfg.replace(init_from=str(tmp_path / "t"))).init_source["elapsed_min"]
    assert chain == pytest.approx(saved["elapsed_s"] / 60 + b_saved["elapsed_s"] / 60)
    assert not torch.equal(_params(b), _params(a))
    (tmp_path / "m.pt").unlink()  # not read on resume
    c = train(ft.replace(iterations=2), tmp_path / "b", resume=True, progress=False)
    assert not torch.equal(_params(c), _params(b))
    # refused before anything is written: another model's weights
    with pytest.raises(ValueError, match="init_from: .*'nope' does not exist"):
        build_run(cfg.replace(init_from="nope"))
    with pytest.raises(ValueError, match="another configuration .embed_dim 32 there vs 16 here"):
        other = cfg.replace(init_from=str(tmp_path / "a"), amat={"embed_dim": 16})
        train(other, tmp_path / "d", progress=False)
    assert not (tmp_path / "d").exists()
    # only the pooled grid differs: a finer multiple starts from the coarse weights (amat.weights.finer_pool)
    fine = build_run(cfg.replace(init_from=str(tmp_path / "a"), amat={**cfg.model.amat, "pool": 8}))
    assert fine.init_source["pool"] == [4, 8] and torch.equal(fine.model.obs_fc1.bias, a.obs_fc1.bias)
    with pytest.raises(ValueError, match="init_from .* pool 6 is not a multiple of 4"):
        build_run(cfg.replace(init_from=str(tmp_path / "a"), amat={**cfg.model.amat, "pool": 6}))


def test_a_cell_goal_model_starts_a_run_on_the_other_mask(tmp_path):
    from catmip_rl.amat.config import AmatConfig
    from catmip_rl.amat.pointer import make_model
    from catmip_rl.store.checkpoint import save_model
    from catmip_rl.training.train import build_run

    known = make_model(AmatConfig(embed_dim=16, goals="cell", cell_channels=8, cell_layers=2))
    save_model(known, tmp_path / "known.pt")
    amat = {"embed_dim": 16, "goals": "cell", "cell_channels": 8, "cell_layers": 2, "cell_mask": "reachable"}
    run = build_run(make_train_config("tiny", amat=amat, init_from=str(tmp_path / "known.pt")))
    assert run.model.config.cell_mask == "reachable" and run.init_source["cell_mask"] == [
        "known",
        "reachable",
    ]
    assert torch.equal(_params(run.model), _params(known))  # the mask holds no weights
    with pytest.raises(ValueError, match="another configuration .cell_channels 8 there vs 16 here"):
        build_run(
            make_train_config("tiny", amat=amat | {"cell_channels": 16}, init_from=str(tmp_path / "known.pt"))
        )


def test_export_writes_a_runs_model_with_its_provenance(tmp_path, capsys):
    from catmip_rl.store.checkpoint import load_model

    run, out = tmp_path / "run", tmp_path / "m.pt"
    cfg = make_train_config("tiny", iterations=2, eval_every=0)
    model = train(cfg, run, progress=False)
    assert cli(["export", str(run), "--out", str(out)]) == 0
    assert "iteration 2" in capsys.readouterr().out
    assert torch.equal(_params(load_model(out)), _params(model)) and out.with_suffix(".json").exists()
    extra = torch.load(out, weights_only=True)["extra"]
    assert extra["iteration"] == 2 and extra["episodes"] == 16 and extra["training_minutes"] > 0
    assert TrainConfig.from_json(json.dumps(extra["train_config"])) == cfg and extra["cpu_capability"]
    # never overwritten without --force; with it, from one checkpoint file
    before = out.read_bytes()
    assert cli(["export", str(run), "--out", str(out)]) == 2 and out.read_bytes() == before
    assert "--force" in capsys.readouterr().err
    ckpt = run / "checkpoints" / "iter_000001.pt"
    assert cli(["export", str(ckpt), "--out", str(out), "--force"]) == 0
    assert torch.load(out, weights_only=True)["extra"]["iteration"] == 1
    # never onto the checkpoint it reads, nor onto a file beside --out that it would write
    assert (
        cli(["export", str(ckpt), "--out", str(ckpt), "--force"]) == 2
        and "would replace" in capsys.readouterr().err
    )
    (run / "config.pt").unlink(missing_ok=True)
    assert cli(["export", str(run), "--out", str(run / "config.pt")]) == 2  # config.json is there
    assert "config file" in capsys.readouterr().err and not (run / "config.pt").exists()


def test_a_half_precision_export_is_half_the_bytes_and_loads_as_float32(tmp_path):
    from catmip_rl.store.checkpoint import load_model

    run = tmp_path / "run"
    model = train(make_train_config("tiny", iterations=1, eval_every=0), run, progress=False)
    assert cli(["export", str(run), "--out", str(tmp_path / "full.pt")]) == 0
    assert cli(["export", str(run), "--out", str(tmp_path / "half.pt"), "--half"]) == 0
    blob = torch.load(tmp_path / "half.pt", weights_only=True)
    assert all(v.dtype == torch.float16 for v in blob["state_dict"].values() if v.is_floating_point())
    assert (
        blob["extra"]["half"]
        and (tmp_path / "half.pt").stat().st_size < 0.6 * (tmp_path / "full.pt").stat().st_size
    )
    loaded = _params(load_model(tmp_path / "half.pt"))
    assert loaded.dtype == torch.float32 and not torch.equal(loaded, _params(model))
    torch.testing.assert_close(loaded, _params(model), rtol=2**-10, atol=1e-4)


def test_a_fine_tuning_preset_needs_init_from(tmp_path, capsys):
    assert cli(["train", "--preset", "general-coord", "--run-dir", str(tmp_path / "r")]) == 2
    assert "--init-from" in capsys.readouterr().err and not (tmp_path / "r").exists()


def _start_cli_run(run_dir, *args):
    """``catmip train --preset tiny`` in a process of its own (stderr captured)."""
    import subprocess
    import sys

    cmd = [sys.executable, "-m", "catmip_rl.cli", "train", "--preset", "tiny", "--run-dir", str(run_dir),
           "--no-progress", "--threads", "1", *args]  # fmt: skip
    return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


def _wait_for(path, proc, timeout=300.0):
    import time

    end = time.monotonic() + timeout
    while not path.exists():
        assert proc.poll() is None, f"the run ended before writing {path}: {proc.stderr.read()}"
        assert time.monotonic() < end, f"no {path} after {timeout:.0f} s"
        time.sleep(0.05)


@pytest.mark.slow
def test_a_run_dir_in_use_refuses_a_second_writer_and_the_live_run_finishes_untouched(tmp_path, capsys):
    from catmip_rl.training.run_dir import LOCK_NAME

    iterations = ["--set", "iterations=20", "--set", "eval_every=0"]
    live = _start_cli_run(tmp_path / "r", *iterations)
    try:
        _wait_for(tmp_path / "r" / "config.json", live)  # its first checkpoint may or may not be there yet
        for resume in (["--resume"], []):  # resuming it, or starting it anew: both refused
            assert cli(["train", "--preset", "tiny", "--run-dir", str(tmp_path / "r"), *resume]) == 2
            err = capsys.readouterr().err.strip()
            assert f"is in use by process {live.pid} (" in err and "\n" not in err and "Traceback" not in err
        assert live.wait(timeout=600) == 0, live.stderr.read()
    finally:
        live.kill()
    alone = train(
        make_train_config("tiny", iterations=20, eval_every=0, threads=1), tmp_path / "alone", progress=False
    )
    latest = tmp_path / "r" / "checkpoints" / "latest.pt"
    assert torch.load(latest, weights_only=False)["iteration"] == 20
    assert torch.equal(_params(alone), _params(load_model(latest)))
    assert not list((tmp_path / "r").rglob(".*.tmp*"))
    assert (tmp_path / "r" / LOCK_NAME).exists()  # left (unlocked) for the next run: it resumes at once
    train(make_train_config("tiny", iterations=21, eval_every=0), tmp_path / "r", resume=True, progress=False)


@pytest.mark.slow
def test_a_run_killed_at_any_moment_resumes_to_the_weights_of_an_uninterrupted_run(tmp_path):
    import signal

    cfg = make_train_config("tiny", iterations=6, eval_every=0, threads=1)
    uninterrupted = _params(train(cfg, tmp_path / "straight", progress=False))
    for k, wait_for in enumerate(("iter_000001.pt", "iter_000003.pt")):  # killed mid-run, twice
        run = tmp_path / f"killed{k}"
        proc = _start_cli_run(run, "--set", "iterations=6", "--set", "eval_every=0")
        _wait_for(run / "checkpoints" / wait_for, proc)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        resumed = train(cfg, run, resume=True, progress=False)  # no stale lock, no half-written file
        assert torch.equal(_params(resumed), uninterrupted)


def test_a_mixture_of_worlds_takes_turns_and_resumes_exactly(tmp_path):
    worlds = [{}, {"map_size": 14, "team": ["rescuer", "explorer", "explorer"], "num_worlds": 4}]
    cfg = make_train_config("tiny", iterations=3, eval_every=0, worlds=worlds, threads=1)
    assert [(env.map_size, env.num_robots, n) for env, n in cfg.world_configs()] == [(12, 2, 8), (14, 3, 4)]
    straight = train(cfg, tmp_path / "a", progress=False)
    rows = list(csv.DictReader((tmp_path / "a" / "metrics.csv").open()))
    assert [(int(r["iteration"]), r["rollout/world"], int(r["episodes"])) for r in rows] == [
        (1, "0", 8), (2, "1", 12), (3, "0", 20)
    ]  # fmt: skip
    ckpts = tmp_path / "a" / "checkpoints"
    (ckpts / "latest.pt").write_bytes((ckpts / "iter_000002.pt").read_bytes())  # rewind to iteration 2
    resumed = train(cfg, tmp_path / "a", resume=True, progress=False)  # iteration 3: world 0 again
    assert torch.equal(_params(straight), _params(resumed))


def test_a_mixture_of_worlds_is_checked(tmp_path):
    with pytest.raises(ValueError, match=r"worlds must be a JSON list of objects"):
        make_train_config("tiny", worlds={"map_size": 14})
    with pytest.raises(ValueError, match=r"worlds\[0\].num_worlds must be an int >= 1"):
        make_train_config("tiny", worlds=[{"num_worlds": 0}])
    with pytest.raises(ValueError, match=r"worlds\[1\]: unknown EnvConfig field"):
        make_train_config("tiny", worlds=[{}, {"map_sise": 14}])
    with pytest.raises(ValueError, match=r"worlds\[0\]: unknown preset"):
        make_train_config("tiny", worlds=[{"preset": "task9"}])
    with pytest.raises(ValueError, match=r"AMAT window 7 differs from worlds\[0\]'s goal window 5"):
        make_train_config("tiny", worlds=[{"window": 5}])
    with pytest.raises(ValueError, match="needs collector 'local'"):
        make_train_config("tiny", worlds=[{}], collector="ray")
    task3 = make_train_config("tiny", worlds=[{"preset": "task3", "num_worlds": 2}]).world_configs()
    assert task3[0][0].map_size == 32 and task3[0][1] == 2


@pytest.mark.slow
@pytest.mark.parametrize("preset", ["paper-warm-sync", "paper-warm-smallma", "general", "general-coord"])
def test_the_issue_presets_build_and_train_an_iteration(preset, tmp_path):
    """The variants' and the general models' presets as `catmip train` runs them, shrunk: a DAgger round
    where they warm-start, then one PPO iteration (general with cell goals; general-coord, the shipped
    model's last stage, fine-tuning the memory model that its entry plays)."""
    cfg = make_train_config(preset)
    if preset == "general-coord":  # a fine-tuning preset: catmip train asks for --init-from
        cfg = cfg.replace(init_from=str(RECORDS / "general-memory" / "amat_general.pt"))
    small = {"num_worlds": 2, "iterations": 1, "eval_every": 0, "threads": 1, "warm_start_rounds": 1,
             "warm_start_steps": 1}  # fmt: skip
    if cfg.env.worlds:
        small["worlds"] = [dict(w, num_worlds=2) for w in cfg.env.worlds]
    run = tmp_path / preset
    train(cfg.replace(**small), run, progress=False)
    rows = list(csv.DictReader((run / "metrics.csv").open()))
    assert [int(r["iteration"]) for r in rows] == [1] and float(rows[0]["samples"]) > 0
    saved = TrainConfig.from_json((run / "config.json").read_text())
    assert saved.env_config().synchronous == (preset == "paper-warm-sync")
    assert saved.amat_config().window == (5 if preset == "paper-warm-smallma" else 7)
    assert saved.amat_config().goals == ("cell" if preset.startswith("general") else "window")
    assert (run / "warm_start.csv").exists()
    assert (run / "init_from.json").exists() == (preset == "general-coord")


def test_a_warm_start_on_a_mixture_imitates_in_every_world(tmp_path):
    worlds = [{}, {"map_size": 14, "team": ["rescuer", "explorer", "explorer"], "num_worlds": 4}]
    cfg = make_train_config("tiny", worlds=worlds, warm_start="nearest", warm_start_rounds=2,
                            warm_start_steps=4, iterations=1, eval_every=0, threads=1)  # fmt: skip
    train(cfg, tmp_path / "a", progress=False)
    rounds = list(csv.DictReader((tmp_path / "a" / "warm_start.csv").open()))
    assert [int(r["episodes"]) for r in rounds] == [12, 24]  # 8 + 4 episodes a round
    assert int(rounds[-1]["buffer_events"]) > 0
    saved = torch.load(tmp_path / "a" / "checkpoints" / "latest.pt", weights_only=False)
    assert saved["episodes"] == 24 + 8  # then PPO iteration 1 in world 0
    sized = cfg.replace(warm_start_worlds=6)
    train(sized, tmp_path / "b", progress=False)
    rounds = list(csv.DictReader((tmp_path / "b" / "warm_start.csv").open()))
    assert [int(r["episodes"]) for r in rounds] == [12, 24]  # 6 in each world


def _anchored(**overrides):
    from catmip_rl.training.train import build_run

    amat = {"embed_dim": 16, "goals": "cell", "cell_channels": 8, "cell_layers": 2, "cell_mask": "reachable"}
    cfg = make_train_config("tiny", amat=amat, anchor="nearest", anchor_coef=0.5, iterations=2, eval_every=0,
                            **overrides)  # fmt: skip
    run = build_run(cfg)
    rollout = run.collector_for(1).collect(run.model, first_episode=0, generator=run.gen,
                                           labeler=run.labeler)  # fmt: skip
    return cfg, run, rollout


def test_the_anchor_labels_every_decision_with_the_planners_cell_and_trains(tmp_path):
    """``anchor``: the planner's own cell goal labels each active robot's decision during PPO, and the
    auxiliary loss toward it is logged (as ``loss/rescue``, whose place it takes)."""
    amat = {"embed_dim": 16, "goals": "cell", "cell_channels": 8, "cell_layers": 2}
    for bad, match in (({"anchor": "rrt"}, "go together"), ({"anchor_coef": 0.5}, "go together"),
                       ({"anchor": "rrt", "anchor_coef": 0.5, "amat": {}}, "cell-goal model"),
                       ({"anchor": "teleport", "anchor_coef": 0.5}, "anchor must be")):  # fmt: skip
        with pytest.raises(ValueError, match=match):
            make_train_config("tiny", **({"amat": amat} | bad))
    cfg, _, rollout = _anchored()
    label, active = rollout.label, rollout.active.astype(bool)
    assert active.any() and (label[active] >= 0).all()  # every decision labelled
    assert (label[active] < cfg.env_config().map_size ** 2).all()  # a cell r * W + c of the map
    train(cfg, tmp_path / "run", progress=False)
    with open(tmp_path / "run" / "metrics.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 and all(float(r["loss/rescue"]) > 0 for r in rows)


def test_an_anchor_on_the_relay_labels_only_the_decisions_its_relay_rule_made():
    """``anchor_on="relay"``: only an explorer that carries the news to a rescuer is labelled; the config
    refuses it with a planner that has no relay rule."""
    from catmip_rl.training.labelers import auxiliary_labeler
    from tests.env.test_teammate_memory import _corridor

    amat = {"embed_dim": 16, "goals": "cell", "cell_channels": 8, "cell_layers": 2, "teammate_memory": True}
    with pytest.raises(ValueError, match="anchor_on 'relay' needs a relay planner"):
        make_train_config("tiny", amat=amat, anchor="rrt", anchor_coef=1.0, anchor_on="relay")
    cfg = make_train_config("tiny", amat=amat, anchor="rrt-relay", anchor_coef=1.0, anchor_on="relay")
    eng, _ = _corridor()  # the explorer (robot 1) knows the target, the rescuer (robot 0) does not
    st = eng.state
    st.heard_tick[0, 1, 0], st.heard_pos[0, 1, 0], st.heard_knows[0, 1, 0] = 0, st.pos[0, 0], False
    assert eng.active[0].all()  # both decide: the rescuer's goal is RRT's, the explorer's the relay's
    labels = auxiliary_labeler(cfg.loss, cfg.seed).act(eng)
    everywhere = auxiliary_labeler(cfg.replace(anchor_on="every").loss, cfg.seed).act(eng)
    assert labels[0, 0] == -1 and everywhere[0, 0] >= 0
    assert labels[0, 1] == everywhere[0, 1] >= 0
    st.heard_knows[0, 1, 0] = True  # nobody left to tell: nothing labelled
    assert (auxiliary_labeler(cfg.loss, cfg.seed).act(eng) == -1).all()


def test_the_anchor_loss_skips_labels_the_models_mask_rules_out():
    import dataclasses

    from catmip_rl.training.gae import build_batch
    from catmip_rl.training.ppo import ppo_loss

    cfg, run, rollout = _anchored()
    n_classes = cfg.env_config().num_classes
    batch, _ = build_batch(rollout, run.value_norm, cfg.loss.gamma, cfg.loss.lam, n_classes, run.device)
    _, stats = ppo_loss(run.model, batch, label_coef=1.0)
    assert 0 < float(stats["loss/rescue"]) < 50
    walls = batch.label.clone()
    walls[batch.trainable.bool()] = 0  # cell (0, 0): the map's wall, which no mask allows
    _, stats = ppo_loss(run.model, dataclasses.replace(batch, label=walls), label_coef=1.0)
    assert float(stats["loss/rescue"]) == 0.0


@pytest.mark.parametrize(
    ("preset", "record"),
    [("general-rrt", "general-dagger-rrt"), ("general-relay", "general-relay"),
     ("general-relay-noise", "general-relay-noise")],
)  # fmt: skip
def test_the_memory_model_chain_presets_are_the_recorded_runs(preset, record):
    """amat_general.pt's stages as named presets: each is its recorded run's config in every field that
    acts (the start's file and the threads are the command's; warm-start fields act only with a warm start;
    the anchor and the critic's LR were added after the first record, off there; a field added after a
    record is at its default)."""
    cfg = json.loads(make_train_config(preset).to_json())
    ran = json.loads((RECORDS / record / "config.json").read_text())
    ignored = {"init_from", "threads", "critic_lr", "anchor", "anchor_coef"} if "anchor" not in ran else {
        "init_from", "threads", "critic_lr"}  # fmt: skip
    ran = {k: v for k, v in json.loads(TrainConfig().to_json()).items() if k not in ran} | ran
    if not ran["warm_start"]:
        ignored |= {k for k in cfg if k.startswith("warm_start_")}
    acting = {k: v for k, v in cfg.items() if k not in ignored}
    assert acting == {k: v for k, v in ran.items() if k not in ignored}
    assert make_train_config(preset).world_configs()[-1][0].teammate_memory == (preset != "general-rrt")


def test_the_last_stage_adds_a_noisy_task3_world_a_round_and_the_coordinated_proposer():
    base, coord = make_train_config("general-relay-noise"), make_train_config("general-coord")
    # the memory model's worlds and a Task-3 world under noise
    assert coord.env.worlds[:-1] == base.env.worlds
    env, n = coord.world_configs()[-1]
    assert (env.map_size, env.slam_noise, n, env.comm_ranges) == (32, 0.05, 16, (None, 4.0, 2.0))
    assert (coord.imitation.warm_start_rounds, coord.imitation.warm_start_worlds) == (4, 32)
    assert coord.loss.anchor_coef == 0.05
    assert coord.model.amat["hint"] == coord.imitation.warm_start == coord.loss.anchor == "rrt-relay-coord"
    assert coord.model.amat == base.model.amat | {"hint": "rrt-relay-coord"}
    # it is its recorded run's config but for the command's flags (run-records/general-coord)
    command = {"init_from", "threads", "iterations", "eval_every", "checkpoint_every", "seed"}
    ran = json.loads((RECORDS / "general-coord" / "config.json").read_text())
    cfg = json.loads(coord.to_json())
    assert {k: cfg[k] for k in cfg.keys() - command} == {k: ran[k] for k in ran.keys() - command}


def test_the_retired_presets_still_build_as_they_were_recorded():
    """The presets that left with their records (run-records/README.md) are kept as full configs in
    docs/notes/retired-presets.json: each still builds with today's TrainConfig, unchanged, so that a
    recorded command can run again; none is still a preset."""
    retired = json.loads(RETIRED.read_text())["presets"]
    assert len(retired) == 8
    for name, entry in retired.items():
        cfg = TrainConfig.from_json(json.dumps(entry["config"]))
        assert json.loads(cfg.to_json()) == entry["config"], name
        with pytest.raises(ValueError, match="unknown training preset"):
            make_train_config(name)
    # general-coord is general-hint-noise3 (general-hint with a noisy Task-3 world) with another proposer
    hint, noise3 = (
        TrainConfig.from_json(json.dumps(retired[n]["config"]))
        for n in ("general-hint", "general-hint-noise3")
    )
    assert noise3.env.worlds[:-1] == hint.env.worlds
    coord = make_train_config("general-coord")
    as_noise3 = coord.replace(
        amat=noise3.model.amat, warm_start=noise3.imitation.warm_start, anchor=noise3.loss.anchor
    )
    assert json.loads(as_noise3.to_json()) == retired["general-hint-noise3"]["config"]
