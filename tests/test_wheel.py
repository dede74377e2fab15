"""The release as a user gets it: `make dist`'s build (an sdist, then the wheel built from it) installs in a
clean venv outside the repository, and there runs (1) a PettingZoo episode with only the env installed
(no torch), (2) `catmip --help` and `catmip eval --method nearest` env-only, then (3) with the rl extra
`catmip eval --method amat:task1` (the shipped model, read from the installed wheel).

About 3.5 to 4 minutes on 2 cores (205 and 230 s measured beside a niced benchmark): the build ~10 s; the
env's dependencies ~15 s; numba compiles the env's kernels in the fresh install (~35 s); torch's CPU wheel
and the rl extra's other packages ~60 s (torch first, as the Makefile does, so that nothing pulls a CUDA
build); AMAT's execution kernels ~45 s. Everything comes from the package index the machine's pip is set
up with."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pytest

import catmip_env

ROOT = Path(__file__).resolve().parents[1]
TORCH = "torch==2.13.0"  # the Makefile's: the CPU wheel
IGNORE = shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc", "*.pyc")
# the venv's own interpreter and packages only: nothing of this checkout or its .venv leaks in
ENV = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME")}
ENV_ONLY_EPISODE = """
import importlib.util, sys
assert importlib.util.find_spec("torch") is None, "torch is installed"
import pettingzoo
import catmip_env
from catmip_env import search_rescue_v0
assert catmip_env.__file__.startswith(sys.prefix), catmip_env.__file__  # the installed wheel's
env = search_rescue_v0.parallel_env(preset="task1")
obs, infos = env.reset(seed=0)
steps = 0
while env.agents:
    actions = {r: env.action_space(r).sample(mask=obs[r]["action_mask"]) for r in env.agents}
    obs, rewards, terminations, truncations, infos = env.step(actions)
    steps += 1
registered = pettingzoo.make("parallel", "catmip/SearchRescue-v0", preset="task1")
registered.reset(seed=0)
print(catmip_env.__version__, steps, "torch" in sys.modules)
"""


def _run(cmd: list[str], cwd: Path, timeout: float = 600) -> subprocess.CompletedProcess:
    done = subprocess.run(cmd, cwd=cwd, env=ENV, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, f"{' '.join(map(str, cmd))}: rc {done.returncode}\n{done.stderr[-3000:]}"
    return done


def _build(tmp: Path) -> tuple[Path, Path]:
    """`make dist`'s command (python -m build) on a copy of the sources: (sdist, wheel)."""
    pytest.importorskip("build", reason="the dev extra's build (make installs it)")
    src = tmp / "src"  # a copy: nothing is written into the checkout
    src.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy(ROOT / name, src / name)
    for package in ("catmip_env", "catmip_rl"):
        shutil.copytree(ROOT / package, src / package, ignore=IGNORE)
    _run([sys.executable, "-m", "build", "--outdir", str(tmp / "dist"), str(src)], cwd=tmp)
    (sdist,) = (tmp / "dist").glob("catmip-*.tar.gz")
    (wheel,) = (tmp / "dist").glob("catmip-*.whl")
    return sdist, wheel


def _check_archives(sdist: Path, wheel: Path) -> None:
    version = catmip_env.__version__
    assert sdist.name == f"catmip-{version}.tar.gz" and wheel.name == f"catmip-{version}-py3-none-any.whl"
    with tarfile.open(sdist) as tar:
        names = set(tar.getnames())
    assert {f"catmip-{version}/{n}" for n in ("LICENSE", "README.md", "pyproject.toml", "PKG-INFO")} <= names
    with zipfile.ZipFile(wheel) as z:
        files = set(z.namelist())
        metadata = z.read(next(n for n in files if n.endswith(".dist-info/METADATA"))).decode()
    assert {"catmip_env/maps/frozen_maps/task2.json", "catmip_rl/models/amat_task1.pt"} <= files
    assert not any("__pycache__" in n or n.endswith((".nbi", ".nbc")) for n in files)
    assert f"Version: {version}\n" in metadata and "Classifier: Development Status :: 5" in metadata
    assert "Requires-Dist: torch" in metadata and "extra == " in metadata  # torch only with an extra
    assert wheel.stat().st_size < 25e6  # 12.3 MB in 1.0.0, 11.9 MB of it the models


@pytest.mark.slow
def test_the_wheel_installs_in_a_clean_venv_and_runs_env_only_then_with_the_rl_extra(tmp_path):
    sdist, wheel = _build(tmp_path)
    _check_archives(sdist, wheel)
    venv, work = tmp_path / "venv", tmp_path / "work"  # outside the repository
    work.mkdir()
    _run([sys.executable, "-m", "venv", str(venv)], cwd=work)
    python, catmip = str(venv / "bin" / "python"), str(venv / "bin" / "catmip")
    pip = [python, "-m", "pip", "install", "--quiet", "--disable-pip-version-check"]
    _run([*pip, str(wheel)], cwd=work)

    # (1) the env alone: a PettingZoo episode, no torch installed
    version, steps, torch_loaded = _run([python, "-c", ENV_ONLY_EPISODE], cwd=work).stdout.split()
    assert version == catmip_env.__version__ and int(steps) > 0 and torch_loaded == "False"

    # (2) the command env-only: help, and the planners' evaluation with its results (no plots: no matplotlib)
    assert "eval" in _run([catmip, "--help"], cwd=work).stdout
    nearest = [catmip, "eval", "--method", "nearest", "--episodes", "4", "--out", "nearest", "--no-progress"]
    done = _run(nearest, cwd=work)
    written = {p.name for p in (work / "nearest").iterdir()}
    assert written == {"episodes.csv", "episodes.json", "curve.csv", "summary.json", "run.json"}
    assert json.loads((work / "nearest" / "summary.json").read_text())["map_set_status"] == "verified"
    assert "no curve.png" in done.stderr and "catmip[render]" in done.stderr
    model = subprocess.run([catmip, "eval", "--method", "amat:task1", "--episodes", "1", "--out", "amat0"],
                           cwd=work, env=ENV, capture_output=True, text=True, timeout=300)  # fmt: skip
    assert model.returncode == 2 and "'rl' extra" in model.stderr and "Traceback" not in model.stderr

    # (3) with the rl extra: the shipped Task-1 model from the installed wheel
    _run([*pip, TORCH], cwd=work)
    _run([*pip, f"{wheel}[rl]"], cwd=work)
    cuda = _run([python, "-c", "import torch; print(torch.version.cuda)"], cwd=work).stdout.strip()
    assert cuda == "None", f"a CUDA build of torch was installed ({cuda})"
    _run([catmip, "eval", "--method", "amat:task1", "--episodes", "4", "--out", "amat", "--no-progress",
          "--argmax-only"], cwd=work)  # fmt: skip
    summary = json.loads((work / "amat" / "summary.json").read_text())
    assert summary["method"] == "amat_task1" and summary["episodes"] == 4
    assert (work / "amat" / "curve.png").is_file()  # matplotlib came with the rl extra


def test_the_release_has_its_changelog_entry_and_make_dist_its_builder():
    version = catmip_env.__version__
    changelog = (ROOT / "CHANGELOG.md").read_text()
    assert f"\n## [{version}] - " in changelog and f"\n[{version}]: " in changelog
    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
    dev = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]["dev"]
    assert any(req.startswith("build") for req in dev)  # from the index by name, like every dev tool
    makefile = (ROOT / "Makefile").read_text()
    assert "\ndist: $(STAMP)\n" in makefile and "$(PY) -m build --outdir dist ." in makefile
