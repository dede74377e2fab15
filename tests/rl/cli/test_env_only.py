"""``catmip`` as ``pip install catmip`` gives it (numpy, numba, gymnasium, pettingzoo; no torch, no
matplotlib): the planners evaluate and the results are written; the missing plots are one line, and
``--no-plots`` skips them explicitly. (tests/test_wheel.py runs the same from a built wheel.)"""

from __future__ import annotations

import json
import subprocess
import sys

from catmip_rl.cli.main import main

# every module of an extra (pyproject's optional dependencies): absent, as in an env-only install
EXTRAS = ("torch", "torchrl", "tensordict", "tensorboard", "tqdm", "matplotlib", "imageio", "PIL", "scipy",
          "rliable", "arch", "pandas", "ray")  # fmt: skip
ENV_ONLY = f"""
import sys
for name in {EXTRAS!r}:
    sys.modules[name] = None  # import fails, find_spec says absent: as if it were not installed
from catmip_rl.cli.main import main
sys.exit(main(sys.argv[1:]))
"""
RESULTS = {"episodes.csv", "episodes.json", "curve.csv", "summary.json", "run.json"}


def catmip_env_only(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", ENV_ONLY, *args], capture_output=True, text=True)


def _notes(stderr: str) -> list[str]:
    """stderr's lines but the one-time kernel compilation's."""
    return [line for line in stderr.splitlines() if line.strip() and not line.startswith("catmip: compil")]


def test_env_only_eval_writes_its_results_and_says_in_one_line_that_plots_need_the_render_extra(tmp_path):
    out = tmp_path / "nearest"
    done = catmip_env_only("eval", "--method", "nearest", "--episodes", "2", "--out", str(out),
                           "--no-progress")  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert {p.name for p in out.iterdir()} == RESULTS  # no curve.png, nothing else
    assert json.loads((out / "summary.json").read_text())["episodes"] == 2
    assert "nearest on task1" in done.stdout and "curve.png" not in done.stdout.splitlines()[-1]
    (note,) = _notes(done.stderr)
    assert note.startswith("catmip eval: results written, no curve.png")
    assert "pip install 'catmip[render]'" in note and "--no-plots" in note and "Traceback" not in note


def test_env_only_eval_with_no_plots_says_nothing_of_them(tmp_path):
    out = tmp_path / "nearest"
    done = catmip_env_only("eval", "--method", "nearest", "--episodes", "1", "--out", str(out),
                           "--no-progress", "--no-plots")  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert {p.name for p in out.iterdir()} == RESULTS and _notes(done.stderr) == []


def test_env_only_help_and_version():
    for args in (["--help"], ["eval", "--help"], ["--version"]):
        done = catmip_env_only(*args)
        assert done.returncode == 0 and done.stdout and not _notes(done.stderr), (args, done.stderr)
    assert "--no-plots" in catmip_env_only("eval", "--help").stdout


def test_no_plots_skips_the_curve_where_matplotlib_is_installed(tmp_path, capsys):
    out = tmp_path / "nearest"
    assert main(["eval", "--method", "nearest", "--episodes", "1", "--out", str(out), "--no-progress",
                 "--no-plots"]) == 0  # fmt: skip
    assert {p.name for p in out.iterdir()} == RESULTS
    assert "no curve.png" not in capsys.readouterr().err
