"""Frozen map sets: the maps of the evaluation protocol, shipped as manifests of map hashes.

A map depends only on the task, the seed and the episode index (``catmip_env.kernels.rng``), so "maps 0 .. E-1
of seed s" names the same episodes on every machine -- as long as map generation itself does not change
(another catmip version, another numpy or numba). The manifests ``frozen_maps/task1.json`` ..
``task3.json`` hold the hash of each of the first 1,000 maps of the frozen seeds; :func:`check_maps`
compares an evaluation's maps with them, so that numbers from different machines and versions are
comparable or refused::

    hashes = [map_hash(engine, b) for b in range(engine.num_worlds)]
    report = check_maps("task2", seed=0, hashes=hashes)   # MapSetMismatch if they differ
    report.status                                         # "verified" or "not frozen"

The frozen seeds (:data:`FROZEN_SEEDS`): 0 is the paper protocol's (its first 100 maps are the figures'
maps); 1 and 2 are the development sets earlier models were compared and chosen on. The benchmark suite
has two splits (:data:`SPLITS`): **validation**, seed 1000 (:data:`VALIDATION_SEED`), public, for tuning,
gates and every choice (the project chose models and planners on it); and **test**, seed 20261201
(:data:`TEST_SEED`), which nothing was tuned or chosen on: an entry plays it once, after every choice
is frozen.

``python -m catmip_env.maps.map_sets --write`` regenerates the manifests (maintainers, after a deliberate
change of map generation).
"""

from __future__ import annotations

import argparse
import json
import re
import zlib
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from catmip_env.config import make_config
from catmip_env.engines.world import BatchedWorld
from catmip_env.runtime.files import atomic_path

__all__ = [
    "FROZEN_SEEDS",
    "VALIDATION_SEED",
    "TEST_SEED",
    "SPLITS",
    "MANIFEST_EPISODES",
    "MapSetMismatch",
    "MapSetReport",
    "check_maps",
    "manifest",
    "map_hash",
    "map_hashes",
]

VALIDATION_SEED = 1000
"""The suite's validation maps: public, for tuning, gates and every choice (the project chose on them)."""
TEST_SEED = 20261201
"""The suite's test maps: nothing is chosen on them; an entry plays them once, after every choice."""
SPLITS = {"validation": VALIDATION_SEED, "test": TEST_SEED}
FROZEN_SEEDS = (0, 1, 2, VALIDATION_SEED, TEST_SEED)
MANIFEST_EPISODES = 1000
TASKS = ("task1", "task2", "task3")
FORMAT = "catmip-map-set-v1"
HERE = Path(__file__).resolve().parent / "frozen_maps"
_HASH = re.compile(r"[0-9a-f]{8}")  # map_hash's form


def map_hash(engine, b: int) -> str:
    """CRC-32 (hex) of world ``b``'s map, target and start poses: equal hashes = the same episode.
    ``engine``: a ``BatchedWorld`` or an ``EventEngine`` just reset (start poses are read)."""
    st = engine.state
    parts = (st.grid[b], st.target[b], st.pos[b], st.heading[b], st.cls[b])
    return f"{zlib.crc32(b''.join(np.ascontiguousarray(p).tobytes() for p in parts)):08x}"


def map_hashes(task: str, seed: int, episodes: int) -> list[str]:
    """The hashes of maps 0 .. episodes-1 of ``seed`` for a task preset, generated here and now."""
    eng = BatchedWorld(make_config(task), num_worlds=episodes, seed=seed)
    eng.reset(episode_indices=np.arange(episodes))
    return [map_hash(eng, b) for b in range(episodes)]


class MapSetMismatch(ValueError):
    """The maps generated here differ from a frozen map set's."""


@dataclass(frozen=True)
class MapSetReport:
    """What :func:`check_maps` found: ``status`` "verified" (every map matched the manifest), "not
    frozen" (no manifest covers this seed or these episodes) or "differs" (allowed by the caller)."""

    name: str  # "task2/seed0"
    status: str
    verified_episodes: int  # how many of the maps were compared (and matched, unless "differs")
    first_difference: int | None = None  # the first episode whose map differs

    def as_dict(self) -> dict:
        return {
            "map_set": self.name,
            "map_set_status": self.status,
            "map_set_verified_episodes": self.verified_episodes,
            "map_set_first_difference": self.first_difference,
        }


@cache
def manifest(task: str) -> dict:
    """The shipped manifest of a task: ``{"seeds": {"0": [hash, ...], ...}, ...}``."""
    path = HERE / f"{task}.json"
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise ValueError(
            f"the map-set manifest {path} is missing or corrupt ({err}); reinstall catmip"
        ) from None
    if not isinstance(data, dict) or data.get("format") != FORMAT or data.get("task") != task:
        raise ValueError(f"{path} is not a {FORMAT} manifest of {task}")
    problem = _manifest_problem(data)
    if problem:
        raise ValueError(f"the map-set manifest {path} is malformed: {problem}; reinstall catmip")
    return data


def _manifest_problem(data: dict) -> str:
    """What is wrong with a manifest's ``"seeds"`` ('' if nothing): an object holding every frozen seed
    (decimal strings), each a list of MANIFEST_EPISODES map hashes (8 lowercase hex digits, as
    :func:`map_hash` writes them). A seed or maps left out would pass as "not frozen" or go unchecked."""
    seeds = data.get("seeds")
    if not isinstance(seeds, dict):
        return f'"seeds" must be an object {{seed: [hash, ...]}}, got {type(seeds).__name__}'
    missing = [s for s in FROZEN_SEEDS if str(s) not in seeds]
    if missing:
        return f'"seeds" lacks the frozen seed(s) {missing}'
    for seed, hashes in seeds.items():
        if not seed.isdecimal():
            return f'seed {seed!r} of "seeds" is not a non-negative int'
        if not isinstance(hashes, list) or len(hashes) != MANIFEST_EPISODES:
            got = f"{len(hashes)} hashes" if isinstance(hashes, list) else type(hashes).__name__
            return f"seed {seed} must be a list of {MANIFEST_EPISODES} map hashes, got {got}"
        bad = next((e for e, h in enumerate(hashes) if not (isinstance(h, str) and _HASH.fullmatch(h))), None)
        if bad is not None:
            return f"map {bad} of seed {seed} is not a map hash (8 hex digits): {hashes[bad]!r}"
    return ""


def check_maps(
    task: str, seed: int, hashes: list[str], allow_other: bool = False, indices: Any = None
) -> MapSetReport:
    """Compare the hashes of maps 0 .. len(hashes)-1 of ``seed`` (or of the episode ``indices``, in their
    order) with the frozen set of ``task``.

    Raises :class:`MapSetMismatch` (one line: where, and what it means) when a map differs, unless
    ``allow_other`` (the report then says "differs"). Seeds without a manifest are "not frozen"; maps
    past the manifest's 1,000 are not compared (``verified_episodes`` says how many were)."""
    name = f"{task}/seed{seed}"
    if task not in TASKS:
        return MapSetReport(name, "not frozen", 0)
    frozen = manifest(task)["seeds"].get(str(seed))
    if frozen is None:
        return MapSetReport(name, "not frozen", 0)
    episodes = range(len(hashes)) if indices is None else [int(k) for k in indices]
    pairs = [(j, k) for j, k in enumerate(episodes) if k < len(frozen)]
    n = len(pairs)
    if n == 0:  # nothing compared: never "verified"
        return MapSetReport(name, "not frozen", 0)
    first = next(((j, k) for j, k in pairs if hashes[j] != frozen[k]), None)
    diff = None if first is None else first[1]
    if diff is None:
        return MapSetReport(name, "verified", n)
    if not allow_other:
        raise MapSetMismatch(
            f"map {diff} of {name} differs from the frozen map set (hash {hashes[first[0]]}, frozen "
            f"{frozen[diff]}): this installation (catmip, numpy or numba version) generates other maps, so "
            "its numbers are not comparable with results on the frozen set; pass --allow-other-maps "
            "(allow_other_maps=True) to evaluate anyway, recorded as such in the summary"
        )
    return MapSetReport(name, "differs", n, diff)


def _write_manifests() -> None:
    import numba

    import catmip_env

    for task in TASKS:
        seeds = {str(s): map_hashes(task, s, MANIFEST_EPISODES) for s in FROZEN_SEEDS}
        data = {
            "format": FORMAT,
            "task": task,
            "hash": "CRC-32 of the grid, target, start positions, headings and classes (map_sets.map_hash)",
            "episodes": MANIFEST_EPISODES,
            "made_with": {
                "catmip": catmip_env.__version__,
                "numpy": np.__version__,
                "numba": numba.__version__,
            },
            "seeds": seeds,
        }
        path = HERE / f"{task}.json"
        with atomic_path(path) as tmp:
            tmp.write_text(json.dumps(data, separators=(",", ":")) + "\n")
        print(f"wrote {path}")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description="regenerate the frozen map sets' manifests")
    ap.add_argument("--write", action="store_true", help="write frozen_maps/task1.json .. task3.json")
    if ap.parse_args().write:
        _write_manifests()
    else:
        ap.print_help()
