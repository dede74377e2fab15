"""Packaging: one version everywhere, the licence and typing markers ship, extras stay in their lanes."""

from __future__ import annotations

import importlib.metadata
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

import catmip_env

ROOT = Path(__file__).resolve().parents[1]


def _pyproject() -> dict:
    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_versions_agree():
    pytest.importorskip("torch")
    import catmip_rl

    installed = importlib.metadata.version("catmip")
    assert catmip_env.__version__ == catmip_rl.__version__
    assert installed == catmip_env.__version__, (
        f"installed metadata says {installed}, catmip_env.__version__ says {catmip_env.__version__}: "
        "reinstall (pip install -e .) after changing the version"
    )


def test_version_is_written_once():
    project = _pyproject()
    assert "version" not in project["project"]
    assert "version" in project["project"]["dynamic"]
    assert project["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "catmip_env.__version__"}


def test_license_and_typing_markers_ship():
    project = _pyproject()
    assert "MIT License" in (ROOT / "LICENSE").read_text()
    assert project["project"]["license"] == "MIT"
    assert project["project"]["license-files"] == ["LICENSE"]
    data = project["tool"]["setuptools"]["package-data"]
    for package in ("catmip_env", "catmip_rl"):
        assert (ROOT / package / "py.typed").is_file()
        assert "py.typed" in data[package]


def test_extras():
    extras = _pyproject()["project"]["optional-dependencies"]

    def names(extra: str) -> set[str]:  # requirement names, self-references expanded
        out = set()
        for req in extras[extra]:
            if req.startswith("catmip["):
                for sub in req[len("catmip[") : -1].split(","):
                    out |= names(sub.strip())
            else:
                out.add(req.split(">")[0].split("<")[0].split("=")[0].split("[")[0].strip())
        return out

    # every `catmip` subcommand runs with the rl extra: render writes GIFs, bench paper draws figures
    assert {"torch", "torchrl", "tensordict", "imageio", "matplotlib"} <= names("rl")
    # all is what a user runs; test and lint tools are dev's alone
    assert not names("all") & {"pytest", "pytest-xdist", "hypothesis", "ruff"}
    assert {"pytest", "hypothesis", "ruff"} <= names("dev")


def test_wheel_contents(tmp_path):
    """The built wheel carries the licence, both py.typed markers and the shipped model."""
    setuptools = pytest.importorskip("setuptools")
    if int(setuptools.__version__.split(".")[0]) < 77:
        pytest.skip("PEP 639 licence metadata needs setuptools >= 77")
    src = tmp_path / "src"  # build from a copy: nothing is written into the checkout
    src.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy(ROOT / name, src / name)
    for package in ("catmip_env", "catmip_rl"):
        shutil.copytree(ROOT / package, src / package, ignore=shutil.ignore_patterns("__pycache__"))
    cmd = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", "dist", "."]
    subprocess.run(cmd, cwd=src, check=True, capture_output=True)
    (wheel,) = (src / "dist").glob("catmip-*.whl")
    with zipfile.ZipFile(wheel) as z:
        files = set(z.namelist())
        metadata = z.read(next(n for n in files if n.endswith(".dist-info/METADATA"))).decode()
    assert {"catmip_env/py.typed", "catmip_rl/py.typed", "catmip_rl/models/amat_task1.pt"} <= files
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in files)
    assert f"Version: {catmip_env.__version__}\n" in metadata
    assert "License-Expression: MIT\n" in metadata


def test_the_citation_file_names_this_version_and_the_paper():
    cff = (ROOT / "CITATION.cff").read_text()
    top = [line for line in cff.splitlines() if ": " in line and not line.startswith(" ")]
    fields = dict(line.split(": ", 1) for line in top)
    assert fields["cff-version"] == "1.2.0" and fields["version"] == catmip_env.__version__
    assert fields["license"] == _pyproject()["project"]["license"]
    assert "Cooperative and Asynchronous Transformer-Based Mission Planning" in cff and "year: 2025" in cff
