"""Every example and the demo run end to end on a tiny budget."""

import csv
import importlib.util
import json
import math
from pathlib import Path

import pytest
import torch

from catmip_env import make_config
from catmip_env.play import WorldNotSupported

ROOT = Path(__file__).resolve().parents[1]


def _load(path: Path):
    spec = importlib.util.spec_from_file_location(path.stem, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("extra", [[], ["--no-mask"]])
def test_pettingzoo_quickstart(extra):
    episodes = _load(ROOT / "examples" / "pettingzoo_quickstart.py").main(
        ["--preset", "task1", "--episodes", "1", *extra]
    )
    assert len(episodes) == 1 and episodes[0]["decisions"] > 0
    assert (episodes[0]["invalid"] > 0) == bool(extra)  # masked sampling never picks an invalid goal


def test_demo_writes_results_and_gif(tmp_path):
    from catmip_env import demo

    rows = demo.main(
        [
            "--preset",
            "task1",
            "--episodes",
            "4",
            "--planners",
            "nearest,random-rescue",
            "--out",
            str(tmp_path),
        ]
    )
    saved = json.loads((tmp_path / "results.json").read_text())
    assert saved == rows and [r["planner"] for r in saved] == ["nearest", "random-rescue"]
    assert all(0.0 <= r["success_rate"] <= 1.0 and r["episodes"] == 4 for r in saved)
    assert (tmp_path / "results.csv").read_text().startswith("planner,")
    assert (tmp_path / "episode.gif").stat().st_size > 1000


def test_mappo_torchrl_budget_is_the_one_given():
    mod = _load(ROOT / "examples" / "mappo_torchrl.py")
    quick = mod.parse_args([])  # neither budget: five minutes
    assert (quick.minutes, quick.iterations) == (5.0, None)
    long = mod.parse_args(["--iterations", "2000"])  # an iteration budget alone has no time limit
    assert long.minutes is None and mod._spent(long, 600.0, 1000) == 0.5
    both = mod.parse_args(["--iterations", "2000", "--minutes", "10"])  # whichever ends first
    assert mod._spent(both, 6.0, 1000) == 0.6 and mod._spent(both, 1.0, 2000) == 1.0


@pytest.mark.parametrize("algo", ["mappo", "ippo"])
def test_mappo_torchrl_trains_saves_and_evaluates_through_its_factory(tmp_path, algo, capsys, monkeypatch):
    out = tmp_path / algo
    history = _load(ROOT / "examples" / "mappo_torchrl.py").main(
        ["--algo", algo, "--iterations", "2", "--worlds", "8", "--events", "32", "--epochs", "2",
         "--minibatch", "128", "--out", str(out), "--eval-episodes", "3", "--save-every", "1",
         "--pool", "4" if algo == "mappo" else "0"]
    )  # fmt: skip
    assert len(history) == 2
    for row in history:
        assert all(math.isfinite(row[k]) for k in ("loss_objective", "loss_critic", "loss_entropy"))
        assert row["decisions"] > 0
    assert sum(r["episodes"] for r in history) > 0
    assert f"rescued by tick 100 on the protocol's maps: {algo} " in capsys.readouterr().out
    summary = json.loads((out / "eval" / algo / "summary.json").read_text())
    assert summary["policy"] == f"py:{out / 'policy.py'}:make_policy" and summary["episodes"] == 3
    nearest = json.loads((out / "eval" / "nearest" / "episodes.json").read_text())
    mine = json.loads((out / "eval" / algo / "episodes.json").read_text())
    assert [e["map_hash"] for e in mine] == [e["map_hash"] for e in nearest]
    assert len((out / "metrics.csv").read_text().splitlines()) == 3
    # a pooled CNN plays another map size; a flattened one (--pool 0) is refused with one line
    from catmip_rl.cli.main import main as cli

    factory = f"py:{out / 'policy.py'}:make_policy"
    code = cli(["eval", "--task", "task3", "--method", factory, "--episodes", "1",
                "--out", str(tmp_path / "t3"), "--no-progress"])  # fmt: skip
    if algo == "mappo":
        assert code == 0 and (tmp_path / "t3" / "summary.json").is_file()
    else:
        assert code == 2 and "was trained for" in capsys.readouterr().err
    # its learning curve: docs/figures/marl_curves.py reads the run folder
    curves = _load(ROOT / "docs" / "figures" / "marl_curves.py")
    monkeypatch.setattr("sys.argv", ["marl_curves.py", str(out), "--out", str(tmp_path / "curves")])
    curves.main()
    rows = list(csv.DictReader((tmp_path / "curves.csv").open()))
    assert [(r["algo"], int(r["iteration"])) for r in rows] == [(algo, 0), (algo, 1)]
    assert (tmp_path / "curves.png").stat().st_size > 1000


def test_evaluate_my_policy_plays_the_planners_maps_and_compares(tmp_path, capsys):
    example = ROOT / "examples" / "evaluate_my_policy.py"
    rates = _load(example).main(["--episodes", "12", "--out", str(tmp_path)])
    assert set(rates) == {"greedy", "nearest", "random-uniform"}
    assert "| task1-full-noise0-ma10 | greedy | nearest | 12 |" in capsys.readouterr().out
    assert (tmp_path / "compare" / "paired.csv").exists()
    # the same file as a method of the command line, from outside the repository
    from catmip_rl.cli.main import main as cli

    out = tmp_path / "cli"
    assert cli(["eval", "--method", f"greedy=py:{example}:make_policy", "--episodes", "12", "--out", str(out),
                "--no-progress", "--threads", "1"]) == 0  # fmt: skip
    mine = json.loads((out / "episodes.json").read_text())
    ref = json.loads((tmp_path / "eval" / "greedy" / "episodes.json").read_text())
    assert [e["map_hash"] for e in mine] == [e["map_hash"] for e in ref]
    assert [e["rescue_tick"] for e in mine] == [e["rescue_tick"] for e in ref]  # seeded: the same run


def test_mappo_torchrl_resumes_from_its_last_save(tmp_path, capsys):
    mod = _load(ROOT / "examples" / "mappo_torchrl.py")
    out = tmp_path / "run"
    small = ["--worlds", "4", "--events", "16", "--epochs", "1", "--minibatch", "64", "--eval-episodes", "0"]
    with pytest.raises(SystemExit):  # nothing saved yet: one line, no traceback
        mod.main(["--resume", "--out", str(out)])
    assert "holds no state.pt and config.json" in capsys.readouterr().err
    mod.main(["--algo", "ippo", "--iterations", "2", "--save-every", "1", "--out", str(out), *small])
    state = torch.load(out / "state.pt", weights_only=True)
    assert state["iteration"] == 2
    steps = {int(s["step"]) for s in state["optim"]["state"].values()}
    with pytest.raises(SystemExit, match="has spent its budget"):
        mod.main(["--resume", "--out", str(out)])
    with pytest.raises(SystemExit):  # an option beside --resume is refused, not ignored
        mod.main(["--resume", "--out", str(out), "--iterations", "5"])
    assert "not ['iterations']: edit config.json" in capsys.readouterr().err
    with pytest.raises(SystemExit, match="not empty"):  # a finished run is never overwritten
        mod.main(["--iterations", "2", "--out", str(out), *small])
    config = json.loads((out / "config.json").read_text())
    (out / "config.json").write_text(json.dumps({**config, "iterations": 3}))  # a longer budget
    capsys.readouterr()
    history = mod.main(["--resume", "--out", str(out)])
    assert f"resuming {out} at iteration 2" in capsys.readouterr().out
    assert [row["iteration"] for row in history] == [0, 1, 2]  # the saved rows, then the new one
    assert len((out / "metrics.csv").read_text().splitlines()) == 4
    resumed = torch.load(out / "state.pt", weights_only=True)
    assert resumed["iteration"] == 3 and resumed["minutes"] >= state["minutes"]
    # the optimiser went on from its saved moments (Adam's step counts), not from scratch
    assert {int(s["step"]) for s in resumed["optim"]["state"].values()} == {
        s + max(1, history[2]["decisions"] // 64) for s in steps
    }
    assert json.loads((out / "policy.json").read_text())["iteration"] == 2


def test_mappo_torchrl_resumes_from_its_weights_only_snapshot(tmp_path, capsys):
    mod = _load(ROOT / "examples" / "mappo_torchrl.py")
    out = tmp_path / "run"
    small = ["--worlds", "4", "--events", "16", "--epochs", "1", "--minibatch", "64", "--eval-episodes", "0"]
    mod.main(["--algo", "mappo", "--iterations", "2", "--save-every", "1", "--out", str(out), *small])
    snapshot = torch.load(out / "weights.pt", weights_only=True)
    assert snapshot["iteration"] == 2
    assert {v.dtype for part in ("actor", "critic") for v in snapshot[part].values()} == {torch.float16}
    (out / "state.pt").unlink()  # the machine lost: the committed snapshot is what is left
    config = json.loads((out / "config.json").read_text())
    (out / "config.json").write_text(json.dumps({**config, "iterations": 3}))
    capsys.readouterr()
    with pytest.raises(SystemExit):  # never a silent switch to the weights: one line that says how
        mod.main(["--resume", "--out", str(out)])
    assert "it has weights.pt: add --from-weights" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        mod.main(["--from-weights", "--out", str(out)])
    assert "--from-weights goes with --resume" in capsys.readouterr().err
    history = mod.main(["--resume", "--from-weights", "--out", str(out)])
    said = capsys.readouterr().out
    assert "at iteration 2 (" in said and "from weights.pt with a new optimiser" in said
    assert [row["iteration"] for row in history] == [0, 1, 2]
    state = torch.load(out / "state.pt", weights_only=True)  # a full state again from here on
    assert state["iteration"] == 3
    # a new optimiser: Adam's step counts are those of the one iteration since the snapshot
    steps = {int(s["step"]) for s in state["optim"]["state"].values()}
    assert steps == {max(1, history[2]["decisions"] // 64)}
    (out / "weights.pt").write_bytes(b"truncated")
    (out / "config.json").write_text(json.dumps({**config, "iterations": 4}))
    with pytest.raises(SystemExit, match="weights.pt is not readable"):
        mod.main(["--resume", "--from-weights", "--out", str(out)])


def test_mappo_torchrl_starts_from_a_saved_policy_with_a_critic_warmup(tmp_path):
    mod = _load(ROOT / "examples" / "mappo_torchrl.py")
    small = ["--worlds", "4", "--events", "16", "--epochs", "1", "--minibatch", "64", "--eval-episodes", "0"]
    mod.main(["--algo", "ippo", "--iterations", "1", "--out", str(tmp_path / "first"), *small])
    policy = tmp_path / "first" / "policy.pt"
    mod.main(["--algo", "ippo", "--task", "task2", "--seed", "3", "--iterations", "1", "--critic-warmup", "1",
              "--init-from", str(policy), "--out", str(tmp_path / "next"), *small])  # fmt: skip
    before, after = (torch.load(p, weights_only=True) for p in (policy, tmp_path / "next" / "policy.pt"))
    assert before.keys() == after.keys()
    assert all(torch.equal(before[k], after[k]) for k in before)  # warm-up: the critic alone learned
    assert json.loads((tmp_path / "next" / "config.json").read_text())["init_from"] == str(policy)
    with pytest.raises(SystemExit, match="--init-from: .* is not a readable saved policy"):
        mod.main(["--init-from", str(tmp_path / "none.pt"), "--out", str(tmp_path / "bad"), *small])


def test_the_marl_baselines_factories_play_each_world_with_its_map_sizes_run():
    policies = _load(ROOT / "run-records" / "marl-pool4" / "policies.py")
    played = policies.mappo_s0(make_config("task2"), 0)
    saved = torch.load(ROOT / "run-records/marl-pool4/mappo-task2-s0/policy.pt", weights_only=True)
    weights = played.module.module[0].module.state_dict()  # the committed Task-2 run of seed 0
    assert {str(v.dtype) for v in saved.values()} == {"torch.float16"}  # committed in half precision
    assert all(torch.equal(weights[k], v.float()) for k, v in saved.items())  # played as float32
    with pytest.raises(WorldNotSupported, match="no ippo run is trained for 24x24 maps"):
        policies.ippo_s0(make_config("task1", map_size=24), 0)
