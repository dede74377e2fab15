"""What a user clones is the library: the tracked tree stays within its budget, and the only model files
in it are the shipped models (``catmip_rl/models/``) and the files a committed leaderboard entry plays.
An experiment's snapshots live outside the tree (their records index says which commit holds them)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from catmip_rl.benchmark.entry_check import load_entries
from catmip_rl.benchmark.replay import run_files

ROOT = Path(__file__).resolve().parents[1]
TREE_BUDGET = 30_000_000  # bytes of tracked files in the working tree


@pytest.fixture(scope="module")
def tracked() -> list[Path]:
    try:
        out = subprocess.run(
            ["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True, text=True
        ).stdout
    except (OSError, subprocess.CalledProcessError) as err:
        pytest.skip(f"the tree budget is checked in a git checkout ({err})")
    return [ROOT / p for p in out.split("\0") if p]


def test_the_tracked_tree_stays_within_its_budget(tracked):
    sizes = {p: p.stat().st_size for p in tracked if p.is_file()}
    total = sum(sizes.values())
    largest = sorted(sizes, key=sizes.get, reverse=True)[:5]
    assert total <= TREE_BUDGET, (
        f"the tracked tree is {total / 1e6:.1f} MB, over {TREE_BUDGET / 1e6:.0f} MB; largest: "
        + ", ".join(f"{p.relative_to(ROOT)} ({sizes[p] / 1e6:.1f} MB)" for p in largest)
    )


def test_every_tracked_model_file_ships_or_is_played_by_an_entry(tracked):
    played = {
        (ROOT / f["file"]).resolve()
        for entry in load_entries(ROOT / "leaderboard" / "entries")
        for run in entry["runs"]
        for f in run_files(run)
        if not Path(f["file"]).is_absolute()
    }
    shipped = (ROOT / "catmip_rl" / "models").resolve()
    models = [p for p in tracked if p.suffix == ".pt"]
    assert models  # the shipped models at least
    stray = [
        p.relative_to(ROOT) for p in models if p.resolve().parent != shipped and p.resolve() not in played
    ]
    assert not stray, f"model files neither shipped nor played by a leaderboard entry: {stray}"
