"""Model files and checkpoints (``store.checkpoint``, ``store.model_files``): read weights-only, by
name, path or run dir, and verified before they are trusted: flipped bytes, a model too big to
build, entries of the wrong types, another run's checkpoint, random bytes and truncations are each one
line naming the file (exit 2 from the CLI), and nothing large is allocated on the way."""

from __future__ import annotations

import errno
import json
import random
import resource
from pathlib import Path

import pytest
import torch

import catmip_rl
from catmip_rl import AMAT, save_model
from catmip_rl.amat.config import LIMITS, AmatConfig
from catmip_rl.cli.main import main
from catmip_rl.evaluation.methods import parse_method
from catmip_rl.store.checkpoint import SHIPPED_DIR, atomic_torch_save, load_model
from catmip_rl.store.model_files import MAX_PARAMETERS, CheckpointError, read_checkpoint
from catmip_rl.training.presets import make_train_config
from tests.rl.helpers import one_line_error

SHIPPED = SHIPPED_DIR / "amat_task1.pt"


def _flipped(tmp_path, start: int, count: int = 2000):
    data = bytearray(SHIPPED.read_bytes())
    for i in range(start, min(start + count, len(data))):
        data[i] ^= 0xFF
    path = tmp_path / f"flipped_{start}.pt"
    path.write_bytes(bytes(data))
    return path


def test_a_model_file_with_flipped_bytes_is_refused(tmp_path, capsys):
    bad = _flipped(tmp_path, SHIPPED.stat().st_size // 3)
    with pytest.raises(CheckpointError, match="fails its checksum"):
        load_model(bad)
    out = tmp_path / "out"
    assert main(["eval", "--method", f"amat:{bad}", "--episodes", "1", "--out", str(out)]) == 2
    one_line_error(capsys, str(bad), "corrupted")
    assert not out.exists()


def test_a_file_declaring_a_huge_model_is_refused_before_building_it(tmp_path, capsys):
    blob = read_checkpoint(SHIPPED)
    huge = blob | {"config": blob["config"] | {"embed_dim": 8192, "n_blocks": 64}, "state_dict": {}}
    torch.save(huge, tmp_path / "huge.pt")
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with pytest.raises(CheckpointError, match=f"more than a model file may \\({MAX_PARAMETERS:,}\\)"):
        load_model(tmp_path / "huge.pt")
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 200_000  # KB: nothing built
    torch.save(blob | {"config": blob["config"] | {"n_blocks": 10**6}}, tmp_path / "blocks.pt")
    assert main(["eval", "--method", f"amat:{tmp_path / 'blocks.pt'}", "--episodes", "1",
                 "--out", str(tmp_path / "out")]) == 2  # fmt: skip
    one_line_error(capsys, "blocks.pt", "n_blocks must be an int from 1 to 64")


def test_config_fields_are_bounded():
    for name, most in LIMITS.items():
        with pytest.raises(ValueError, match=f"AmatConfig.{name} must be"):
            AmatConfig(**{name: most + 2})


def _training_checkpoint(**changes) -> dict:
    cfg = make_train_config("tiny")
    blob = {"iteration": 3, "episodes": 8, "elapsed_s": 1.0, "bf16": None, "model": {},
            "amat_config": json.loads(cfg.amat_config().to_json()), "optimizer": {},
            "value_norm": {k: torch.zeros((), dtype=torch.float64) for k in ("mean", "mean_sq", "debias")},
            "generator": torch.Generator().get_state(), "torch_rng": torch.get_rng_state(),
            "config": cfg.to_json()}  # fmt: skip
    return blob | changes


@pytest.mark.parametrize(
    "changes, needle",
    [
        ({"iteration": "3"}, "iteration is a str, not int"),
        ({"iteration": True}, "iteration is a bool"),
        ({"episodes": -1}, "must be >= 0"),
        ({"config": {"seed": 1}}, "config is a dict, not str"),
        ({"config": "[1, 2]"}, "not a training config's JSON object"),
        ({"model": [1]}, "model is a list, not dict"),
    ],
)
def test_inconsistent_training_checkpoints_are_one_line_naming_the_file(tmp_path, capsys, changes, needle):
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    torch.save(_training_checkpoint(**changes), run / "checkpoints" / "latest.pt")
    with pytest.raises(CheckpointError, match=needle):
        read_checkpoint(run / "checkpoints" / "latest.pt")
    assert main(["train", "--run-dir", str(run), "--resume"]) == 2
    one_line_error(capsys, "latest.pt", needle)
    assert main(["export", str(run), "--out", str(tmp_path / "m.pt")]) == 2
    one_line_error(capsys, "latest.pt")


def test_resume_refuses_a_checkpoint_whose_parts_do_not_fit_before_building_the_run(tmp_path, capsys):
    from catmip_rl.training.train import build_run

    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    good = build_run(make_train_config("tiny"))
    model = {k: v.clone() for k, v in good.model.state_dict().items()}
    torch.save(_training_checkpoint(model={}), run / "checkpoints" / "latest.pt")
    assert main(["train", "--run-dir", str(run), "--resume"]) == 2
    one_line_error(capsys, "latest.pt", "does not fit the AMAT", "missing keys")
    torch.save(_training_checkpoint(model=model, optimizer={"state": 1}), run / "checkpoints" / "latest.pt")
    assert main(["train", "--run-dir", str(run), "--resume"]) == 2
    one_line_error(capsys, "latest.pt: its optimiser or value normaliser does not fit")


def test_a_model_files_extra_of_wrong_types_is_refused(tmp_path, capsys):
    blob = read_checkpoint(SHIPPED)
    torch.save(blob | {"extra": {"training_minutes": "long"}}, tmp_path / "m.pt")
    assert main(["eval", "--method", f"amat:{tmp_path / 'm.pt'}", "--episodes", "1",
                 "--out", str(tmp_path / "out")]) == 2  # fmt: skip
    one_line_error(capsys, "m.pt", "extra training_minutes is a str")


def test_resume_refuses_another_runs_checkpoint(tmp_path, capsys):
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "config.json").write_text(make_train_config("tiny", seed=1).to_json())
    torch.save(_training_checkpoint(config=make_train_config("tiny", seed=2).to_json()),
               run / "checkpoints" / "latest.pt")  # fmt: skip
    assert main(["train", "--run-dir", str(run), "--resume"]) == 2
    one_line_error(capsys, "another run's", "seed")
    assert json.loads((run / "config.json").read_text())["seed"] == 1  # not rewritten


def test_a_full_disk_while_saving_is_one_oserror_and_the_old_file_stays(tmp_path, monkeypatch):
    path = tmp_path / "latest.pt"
    atomic_torch_save({"x": torch.zeros(2)}, path)

    def full_disk(obj, f):
        try:
            raise OSError(errno.ENOSPC, "No space left on device")
        except OSError:
            raise RuntimeError("[enforce fail at inline_container.cc] unexpected pos") from None  # torch's

    monkeypatch.setattr(torch, "save", full_disk)
    with pytest.raises(
        OSError, match="cannot write .*latest.pt \\(the previous one is kept\\): No space"
    ) as err:
        atomic_torch_save({"x": torch.ones(2)}, path)
    assert err.value.errno == errno.ENOSPC
    monkeypatch.undo()
    assert torch.equal(read_checkpoint(path)["x"], torch.zeros(2))
    assert [p.name for p in tmp_path.iterdir()] == ["latest.pt"]  # no temporary file left


def test_fuzzed_model_files_are_refused_or_load(tmp_path):
    """Random bytes, truncations, flipped bytes anywhere and crafted configs: a CheckpointError or
    another ValueError (one line) every time, or a model that loads; never another exception type."""
    rng = random.Random(0)
    data = SHIPPED.read_bytes()
    cases = [bytes(rng.getrandbits(8) for _ in range(rng.choice([0, 10, 4096]))) for _ in range(3)]
    cases += [data[: rng.randrange(len(data))] for _ in range(8)]
    for _ in range(12):
        flipped = bytearray(data)
        for i in rng.sample(range(len(data)), rng.choice([1, 8])):
            flipped[i] ^= 1 << rng.randrange(8)
        cases.append(bytes(flipped))
    blob = read_checkpoint(SHIPPED)
    for field, value in [("embed_dim", -1), ("window", 2), ("goals", "all"), ("n_heads", 7), ("pool", 1.5),
                         ("local_size", None), ("unknown", 1)]:  # fmt: skip
        path = tmp_path / "crafted.pt"
        torch.save(blob | {"config": blob["config"] | {field: value}}, path)
        cases.append(path.read_bytes())
    outcomes = {"refused": 0, "loaded": 0}
    for k, case in enumerate(cases):
        path = tmp_path / f"case{k}.pt"
        path.write_bytes(case)
        try:
            load_model(path)
            outcomes["loaded"] += 1
        except ValueError as err:  # CheckpointError is one
            assert "\n" not in str(err) and str(path) in str(err), err
            outcomes["refused"] += 1
    assert outcomes["refused"] >= len(cases) - 2, outcomes  # a flip in unread padding may still load


def test_checkpoints_are_read_weights_only(tmp_path):
    import fractions

    torch.save({"x": fractions.Fraction(1, 3)}, tmp_path / "pickle.pt")  # loading it would run code
    with pytest.raises(CheckpointError, match="unsafe"):
        read_checkpoint(tmp_path / "pickle.pt")
    assert set(read_checkpoint(SHIPPED)) == {"format", "config", "state_dict", "extra"}


def test_shipped_models_load_by_name(tmp_path, monkeypatch):
    assert load_model("task1").config.embed_dim == 64
    assert catmip_rl.load_model("task1").config == load_model(SHIPPED).config
    assert Path(parse_method("amat:task1").target) == SHIPPED
    assert parse_method("best=amat-guard:task1").loop_guard
    assert load_model("paper").config.embed_dim == 192  # the Table-2 size
    assert load_model("smallma").config.window == 5  # SmallMA, D = 5
    assert parse_method("amat:sync").synchronous and not parse_method("amat:paper").synchronous  # Synch-AMAT
    general = load_model("general").config  # the second-generation model: cell goals, the teammate memory
    assert (general.goals, general.teammate_memory) == ("cell", True)  # and a coordinated planner's proposals
    assert general.hint == "rrt-relay-coord" and not parse_method("amat:general").loop_guard
    with pytest.raises(FileNotFoundError, match=r"shipped: general, paper, smallma, sync, task1"):
        load_model("task9")
    monkeypatch.chdir(tmp_path)  # a path named like a shipped model wins: paths keep working
    save_model(AMAT(AmatConfig(embed_dim=32)), tmp_path / "task1")
    assert parse_method("amat:task1").target == "task1"
    (tmp_path / "task2").mkdir()  # a folder without a checkpoint is named as such
    with pytest.raises(FileNotFoundError, match=r"no AMAT checkpoint in the folder task2"):
        parse_method("amat:task2")


def test_a_model_loads_from_a_run_dir_or_its_checkpoints_folder(tmp_path):
    (tmp_path / "run" / "checkpoints").mkdir(parents=True)
    (tmp_path / "run" / "checkpoints" / "latest.pt").write_bytes(SHIPPED.read_bytes())
    shipped = load_model(SHIPPED).config
    assert (
        load_model(tmp_path / "run").config == load_model(tmp_path / "run" / "checkpoints").config == shipped
    )
    with pytest.raises(
        FileNotFoundError, match="give a training run dir .* its checkpoints/ folder, or a .pt"
    ):
        load_model(tmp_path)


def test_a_model_file_that_says_so_plays_with_the_loop_guard(tmp_path):
    """``extra["play"]["loop_guard"]``: ``amat:`` plays that file with the loop guard, and says so in its
    summary; other files play without it unless ``amat-guard:`` asks."""
    from catmip_rl.evaluation.evaluate import EvalSetting, evaluate

    model = AMAT(AmatConfig(embed_dim=32))
    plain = save_model(model, tmp_path / "plain.pt")
    guarded = save_model(model, tmp_path / "guarded.pt", extra={"play": {"loop_guard": True}})
    assert not parse_method(f"amat:{plain}").loop_guard and parse_method(f"amat-guard:{plain}").loop_guard
    assert parse_method(f"amat:{guarded}").loop_guard and parse_method(f"amat:{guarded}").name == "guarded"
    setting = EvalSetting("task1", "full", 0.0, 10)
    runs = {p.stem: evaluate(f"amat:{p}", setting, 2, 0, sampled_too=False) for p in (plain, guarded)}
    assert [runs[k].summary["loop_guard"] for k in ("plain", "guarded")] == [False, True]
    torch.save({**read_checkpoint(guarded), "extra": {"play": [1]}}, tmp_path / "bad.pt")
    with pytest.raises(CheckpointError, match="extra play is a list"):
        parse_method(f"amat:{tmp_path / 'bad.pt'}")
