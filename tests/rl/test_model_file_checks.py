"""Archives and checkpoints that are damaged or inconsistent are one line naming the file (and the tensor):
a zip directory whose names are not UTF-8, NaN weights (neither played nor exported), a random state of the
wrong size, a value normaliser that is not one, play options that are not booleans. Also: AMAT's kernels
are compiled only by commands that play a model, and a changed policy file is one readable line."""

from __future__ import annotations

import json
import re

import pytest
import torch

from catmip_rl import AMAT, save_model
from catmip_rl.amat.config import AmatConfig
from catmip_rl.cli.main import main
from catmip_rl.evaluation.methods import parse_method
from catmip_rl.store.checkpoint import SHIPPED_DIR, load_model
from catmip_rl.store.model_files import CheckpointError, read_checkpoint
from tests.rl.helpers import one_line_error
from tests.rl.test_checkpoint import _training_checkpoint

SHIPPED = SHIPPED_DIR / "amat_task1.pt"


def test_a_damaged_zip_directory_names_the_file(tmp_path, capsys):
    data = bytearray(SHIPPED.read_bytes())
    central = data.rfind(b"PK\x01\x02")  # the last central-directory entry: its name made non-UTF-8
    flags_at, name_at = central + 8, central + 46
    data[flags_at] |= 0x08  # keep zipfile's checks going until the name
    data[flags_at + 1] |= 0x08  # bit 11: the name is UTF-8
    data[name_at : name_at + 2] = b"\xff\xfe"
    bad = tmp_path / "damaged.pt"
    bad.write_bytes(bytes(data))
    with pytest.raises(CheckpointError, match="damaged.pt is truncated or corrupted"):
        read_checkpoint(bad)
    assert main(["eval", "--method", f"amat:{bad}", "--episodes", "1", "--out", str(tmp_path / "o")]) == 2
    one_line_error(capsys, str(bad))


def _nan_model(path):
    model = AMAT(AmatConfig(embed_dim=16))
    name, param = next(iter(model.named_parameters()))
    with torch.no_grad():
        param.view(-1)[0] = float("nan")
    return save_model(model, path), name


def test_nan_weights_are_refused_naming_the_tensor(tmp_path, capsys):
    path, name = _nan_model(tmp_path / "nan.pt")
    with pytest.raises(CheckpointError, match=f"nan.pt: its tensor state_dict.{name} holds 1 NaN"):
        load_model(path)
    out = tmp_path / "out"
    assert main(["eval", "--method", f"amat:{path}", "--episodes", "1", "--out", str(out)]) == 2
    one_line_error(capsys, "nan.pt", f"state_dict.{name}")
    assert not out.exists()


@pytest.mark.parametrize(
    "change, needle",
    [
        (
            {"torch_rng": torch.zeros(10, dtype=torch.uint8)},
            "its torch_rng is a torch.uint8 random state of shape (10,)",
        ),
        ({"generator": torch.zeros(3, dtype=torch.uint8)}, "its generator is a torch.uint8 random state"),
        ({"value_norm": {"mean": 1.0}}, "its value_norm is not a value normaliser's state"),
        (
            {
                "value_norm": {
                    k: torch.tensor(float("nan"), dtype=torch.float64) for k in ("mean", "mean_sq", "debias")
                }
            },
            "its tensor value_norm.mean holds 1 NaN",
        ),
        ({"model": {"w": torch.tensor([1.0, float("inf")])}}, "its tensor model.w holds 1 NaN or infinite"),
        ({"elapsed_s": float("nan")}, "its elapsed_s is nan"),
    ],
)
def test_inconsistent_checkpoints_are_one_line(tmp_path, capsys, change, needle):
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    vn = {k: torch.zeros((), dtype=torch.float64) for k in ("mean", "mean_sq", "debias")}
    torch.save(_training_checkpoint(value_norm=vn) | change, run / "checkpoints" / "latest.pt")
    with pytest.raises(CheckpointError, match=needle.replace("(", r"\(").replace(")", r"\)")):
        read_checkpoint(run / "checkpoints" / "latest.pt")
    assert main(["train", "--run-dir", str(run), "--resume"]) == 2
    one_line_error(capsys, "latest.pt", needle)
    assert main(["export", str(run), "--out", str(tmp_path / "m.pt")]) == 2  # nothing exported
    one_line_error(capsys, "latest.pt", needle)
    assert not (tmp_path / "m.pt").exists()


@pytest.mark.parametrize("value", ["no", 0, 1, None, [True]])
def test_play_options_must_be_booleans(tmp_path, value):
    model = AMAT(AmatConfig(embed_dim=16))
    path = save_model(model, tmp_path / "m.pt", extra={"play": {"loop_guard": value}})
    with pytest.raises(CheckpointError, match=re.escape(f"its extra play loop_guard is {value!r}")):
        parse_method(f"amat:{path}")
    ok = save_model(model, tmp_path / "ok.pt", extra={"play": {"loop_guard": False}})
    assert not parse_method(f"amat:{ok}").loop_guard


def test_amat_kernels_compile_only_where_a_model_plays(tmp_path, monkeypatch):
    from catmip_env.runtime import warmup as env_warmup
    from catmip_rl.cli import warmup

    compiled = []
    monkeypatch.setattr(env_warmup, "compile_once", lambda _p, what, _fn, _s: compiled.append(what) or 0.0)
    monkeypatch.setattr(env_warmup, "compile_kernels", lambda _s: 0.0)
    policy = tmp_path / "p.py"
    policy.write_text("class P:\n    def act(self, engine):\n        return engine.masks.argmax(-1)\n"
                      "def make(c, s):\n    return P()\n")  # fmt: skip
    assert main(["eval", "--method", f"py:{policy}:make", "--episodes", "1", "--out", str(tmp_path / "a"),
                 "--no-progress", "--no-plots"]) == 0  # fmt: skip
    assert compiled == []
    assert main(["eval", "--method", "m=amat:task1", "--episodes", "1", "--out", str(tmp_path / "b"),
                 "--no-progress", "--no-plots", "--argmax-only"]) == 0  # fmt: skip
    assert compiled == ["AMAT's numba kernels"]
    assert warmup.plays_amat(["x=sync:amat:task1"]) and warmup.plays_amat(None)
    assert not warmup.plays_amat(["nearest", "MAPPO=py:a.py:m,py:b.py:m", "window:rrt"])


def test_a_changed_policy_file_is_one_readable_line(tmp_path):
    from catmip_rl.benchmark.jobs import Job, run_one
    from catmip_rl.evaluation.evaluate import EvalSetting

    policy = tmp_path / "p.py"
    policy.write_text("class P:\n    def act(self, engine):\n        return engine.masks.argmax(-1)\n"
                      "def make(c, s):\n    return P()\n")  # fmt: skip
    job = Job(
        parse_method(f"py:{policy}:make"), EvalSetting("task1"), 1, 0, str(tmp_path / "out"), resume=True
    )
    run_one(job)
    policy.write_text(policy.read_text() + "# changed\n")
    with pytest.raises(ValueError) as err:
        run_one(job)
    message = str(err.value)
    assert f"played before {policy} changed (its SHA-256 " in message and "{" not in message, message
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["method"] == "p"
