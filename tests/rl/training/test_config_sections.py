"""TrainConfig in sections (training.sections): every field keeps its flat name for the flags, ``--set``,
``replace`` and the JSON; flat and sectioned JSON load to the same config; every committed run record's
config still loads, unchanged; the presets keep their values; errors name the field."""

import dataclasses
import json
from pathlib import Path

import pytest
import torch

from catmip_rl.cli.main import main as cli
from catmip_rl.cli.parser import TRAIN_FLAGS, build_parser
from catmip_rl.training.config import TrainConfig, field_docs, field_types
from catmip_rl.training.presets import TRAIN_PRESETS, make_train_config
from catmip_rl.training.sections import SECTIONS, LossSection, OptimSection

ROOT = Path(__file__).parents[3]

# TrainConfig's fields as they were before the sections (one flat dataclass): each keeps its name
FLAT_FIELDS = """env_preset env_overrides worlds amat num_worlds iterations budget_minutes target_kl epochs
minibatches micro_batch lr critic_lr adam_eps clip value_clip huber_delta entropy_coef value_coef rescue_coef
rescue_heading anchor anchor_coef anchor_on max_grad_norm gamma lam seed device threads precision
update_processes warm_start init_from warm_start_heading warm_start_stay warm_start_value warm_start_relay
warm_start_worlds warm_start_rounds warm_start_steps warm_start_batch warm_start_lr value_warmup_iterations
eval_every eval_episodes eval_seed checkpoint_every collector ray_workers ray_address""".split()

# catmip train's flags before the sections, each with a value to give it and the value it sets
FLAGS = {
    "iterations": ("--iterations", "7", 7),
    "num_worlds": ("--num-worlds", "8", 8),
    "epochs": ("--epochs", "3", 3),
    "minibatches": ("--minibatches", "2", 2),
    "micro_batch": ("--micro-batch", "64", 64),
    "lr": ("--lr", "0.001", 0.001),
    "seed": ("--seed", "5", 5),
    "device": ("--device", "cpu", "cpu"),
    "threads": ("--threads", "1", 1),
    "update_processes": ("--update-processes", "1", 1),
    "warm_start": ("--warm-start", "rrt", "rrt"),
    "init_from": ("--init-from", "runs/a", "runs/a"),
    "target_kl": ("--target-kl", "0.02", 0.02),
    "precision": ("--precision", "bf16", "bf16"),
    "budget_minutes": ("--minutes", "1.5", 1.5),
    "eval_every": ("--eval-every", "3", 3),
    "eval_episodes": ("--eval-episodes", "5", 5),
    "checkpoint_every": ("--checkpoint-every", "4", 4),
    "collector": ("--collector", "ray", "ray"),
    "ray_workers": ("--ray-workers", "4", 4),
    "ray_address": ("--ray-address", "auto", "auto"),
}


def _sectioned(cfg: TrainConfig) -> str:
    """``cfg`` as the sectioned JSON: {"optim": {"lr": ...}, ..., "seed": 0, ...}."""
    return json.dumps(dataclasses.asdict(cfg))


def _records() -> list[Path]:
    """The committed run records' training configs (the MARL baselines' config.json is their own script's)."""
    paths = sorted((ROOT / "run-records").glob("**/config.json"))
    return [p for p in paths if not p.relative_to(ROOT / "run-records").parts[0].startswith("marl-")]


def test_every_field_keeps_its_name_its_doc_and_one_section():
    assert sorted(field_types()) == sorted(FLAT_FIELDS)
    assert sorted(field_docs()) == sorted(FLAT_FIELDS)  # catmip train --help and the docs show each
    assert not set(SECTIONS) & set(FLAT_FIELDS)  # a section's name never shadows a field's
    cfg = TrainConfig()
    assert sorted(cfg.to_dict()) == sorted(FLAT_FIELDS)
    assert isinstance(cfg.optim, OptimSection) and isinstance(cfg.loss, LossSection)
    assert (cfg.optim.lr, cfg.loss.gamma, cfg.eval.eval_seed, cfg.seed) == (1e-4, 1.0, 12_345, 0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.optim.lr = 1.0  # type: ignore[misc]


@pytest.mark.parametrize("name", sorted(TRAIN_PRESETS))
def test_flat_and_sectioned_json_load_to_the_same_config(name):
    cfg = TRAIN_PRESETS[name]
    flat = cfg.to_json()
    assert TrainConfig.from_json(flat) == cfg == TrainConfig.from_json(_sectioned(cfg))
    assert TrainConfig.from_json(_sectioned(cfg)).to_json() == flat  # saved flat, byte for byte
    assert json.loads(flat) == cfg.to_dict()  # config.json stays flat: {"lr": ..., "seed": ...}


def test_every_committed_run_record_config_loads_unchanged():
    records = _records()
    assert len(records) >= 7
    defaults = TrainConfig().to_dict()
    for path in records:
        text = path.read_text()
        cfg = TrainConfig.from_json(text)
        saved = json.loads(text)
        # every field it names has its value; a field added after it is at its default
        assert cfg.to_dict() == defaults | saved, path
        assert TrainConfig.from_json(cfg.to_json()) == cfg == TrainConfig.from_json(_sectioned(cfg)), path
        if saved.keys() == defaults.keys():  # written with every field of today: the same bytes
            assert cfg.to_json() == text.rstrip("\n"), path


def test_every_flag_of_before_parses_to_the_same_field_and_value():
    assert {name: flag for name, (flag, _, _) in FLAGS.items()} == TRAIN_FLAGS
    parser = build_parser()
    for name, (flag, text, value) in FLAGS.items():
        args = parser.parse_args(["train", "--run-dir", "run", flag, text])
        assert getattr(args, name) == value, flag
        assert TrainConfig().replace(**{name: getattr(args, name)}).to_dict()[name] == value, flag


def test_every_field_is_reached_by_its_flat_name_as_set_does():
    cfg = make_train_config("tiny")
    for name, value in cfg.to_dict().items():
        assert cfg.replace(**{name: value}) == cfg, name
    assert cfg.replace(lr=1e-3, seed=3) == cfg.replace(optim={"lr": 1e-3}, seed=3)
    assert cfg.replace(optim=dataclasses.replace(cfg.optim, lr=1e-3)).optim.lr == 1e-3


def test_a_preset_keeps_its_values():
    defaults = TrainConfig().to_dict()
    changed = {k: v for k, v in make_train_config("task1-warm").to_dict().items() if v != defaults[k]}
    assert changed == {
        "env_preset": "task1", "env_overrides": {"activation": [2, 5]}, "amat": {"embed_dim": 64},
        "clip": 0.1, "iterations": 2000, "lr": 3e-4, "epochs": 6, "minibatches": 4, "target_kl": 0.01,
        "value_warmup_iterations": 5, "warm_start": "nearest", "warm_start_rounds": 12,
        "warm_start_steps": 300, "eval_every": 10, "eval_episodes": 64, "eval_seed": 2025,
        "checkpoint_every": 20,
    }  # fmt: skip
    tiny = make_train_config("tiny")
    assert (tiny.collection.num_worlds, tiny.optim.iterations, tiny.optim.epochs) == (8, 2, 2)
    assert (tiny.eval.eval_every, tiny.eval.eval_episodes, tiny.checkpoint_every) == (1, 4, 1)
    assert tiny.model.amat == {"embed_dim": 32} and tiny.env.env_overrides["map_size"] == 12


def test_errors_name_the_field():
    with pytest.raises(ValueError, match=r"unknown TrainConfig field\(s\) \['learning_rate'\]"):
        TrainConfig().replace(learning_rate=1.0)
    with pytest.raises(ValueError, match=r"unknown TrainConfig field\(s\) \['optim.clip'\]"):
        TrainConfig.from_json('{"optim": {"clip": 0.1}}')  # clip is the loss section's
    with pytest.raises(ValueError, match="TrainConfig.lr must be a finite number > 0, got -1"):
        TrainConfig.from_json('{"optim": {"lr": -1}}')
    with pytest.raises(ValueError, match="TrainConfig.eval_seed must be an int"):
        make_train_config("tiny", eval_seed=1.5)
    with pytest.raises(ValueError, match=r"\['lr'\] given twice"):
        TrainConfig.from_json('{"lr": 0.001, "optim": {"lr": 0.002}}')
    with pytest.raises(ValueError, match=r"TrainConfig.optim must be its section \(OptimSection\), got 5"):
        TrainConfig().replace(optim=5)


def test_a_run_whose_config_is_sectioned_or_older_resumes(tmp_path):
    """A run dir written by hand in the sectioned form, its checkpoint's config from before some fields
    existed (as the records of run-records/general-dagger-rrt): --resume reads both, goes on, and writes
    config.json flat again."""
    run = tmp_path / "run"
    cfg = make_train_config("tiny", iterations=1, eval_every=0)
    assert cli(["train", "--preset", "tiny", "--iterations", "1", "--eval-every", "0", "--run-dir", str(run),
                "--no-progress"]) == 0  # fmt: skip
    (run / "config.json").write_text(_sectioned(cfg))
    latest = run / "checkpoints" / "latest.pt"
    saved = torch.load(latest, weights_only=False)
    older = {k: v for k, v in cfg.to_dict().items() if k not in ("critic_lr", "anchor", "anchor_coef")}
    saved["config"] = json.dumps(older)
    torch.save(saved, latest)
    assert cli(["train", "--run-dir", str(run), "--resume", "--iterations", "2", "--no-progress"]) == 0
    assert (run / "config.json").read_text() == cfg.replace(iterations=2).to_json()
    assert torch.load(latest, weights_only=False)["iteration"] == 2


def test_the_constructor_takes_the_flat_names_as_before():
    """Scripts written for the flat config (``TrainConfig(lr=3e-4, num_worlds=32)``) build the same config."""
    cfg = TrainConfig(lr=3e-4, num_worlds=32, seed=3, warm_start_rounds=2)
    assert cfg == TrainConfig().replace(lr=3e-4, num_worlds=32, seed=3, warm_start_rounds=2)
    assert (cfg.optim.lr, cfg.collection.num_worlds, cfg.seed, cfg.imitation.warm_start_rounds) == (
        3e-4,
        32,
        3,
        2,
    )
    assert TrainConfig(optim=cfg.optim) == TrainConfig(lr=3e-4)
    with pytest.raises(ValueError, match=r"unknown TrainConfig field\(s\) \['lrr'\]"):
        TrainConfig(lrr=3e-4)
