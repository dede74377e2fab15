"""The frozen map sets: this installation generates the shipped maps, and other maps are refused."""

from __future__ import annotations

import copy
import json
import re
from pathlib import Path

import pytest

from catmip_env.maps import map_sets
from catmip_env.maps.map_sets import (
    FROZEN_SEEDS,
    MANIFEST_EPISODES,
    MapSetMismatch,
    check_maps,
    manifest,
    map_hashes,
)  # fmt: skip


@pytest.mark.parametrize("task", ["task1", "task2", "task3"])
def test_this_installation_generates_the_frozen_maps(task):
    data = manifest(task)
    assert sorted(int(s) for s in data["seeds"]) == sorted(FROZEN_SEEDS)
    for seed in FROZEN_SEEDS:
        frozen = data["seeds"][str(seed)]
        assert len(frozen) == MANIFEST_EPISODES and len(set(frozen)) == MANIFEST_EPISODES  # all distinct
        # the first maps and a stretch further in: generated here and now, on this CPU and numba
        assert map_hashes(task, seed, 40) == frozen[:40]
    assert check_maps(task, 0, map_hashes(task, 0, 100)).status == "verified"


def test_other_maps_are_refused_unless_allowed():
    hashes = map_hashes("task2", 0, 5)
    hashes[3] = "00000000"
    with pytest.raises(MapSetMismatch, match=r"map 3 of task2/seed0 differs from the frozen map set"):
        check_maps("task2", 0, hashes)
    report = check_maps("task2", 0, hashes, allow_other=True)
    assert (report.status, report.first_difference, report.verified_episodes) == ("differs", 3, 5)
    assert check_maps("task2", 77, hashes).status == "not frozen"
    assert check_maps("task2", 1, map_hashes("task2", 1, 3)).as_dict()["map_set_verified_episodes"] == 3


def test_maps_past_the_manifest_are_not_compared():
    report = check_maps("task1", 0, map_hashes("task1", 0, MANIFEST_EPISODES) + ["ffffffff"])
    assert report.status == "verified" and report.verified_episodes == MANIFEST_EPISODES


# -- tampered manifests: one ValueError naming the file and the problem, never "verified" on nothing ----
@pytest.fixture
def tampered(tmp_path, monkeypatch):
    """``tampered(change)``: task2's manifest, changed by ``change(data)``, shipped from ``tmp_path``."""
    real = json.loads((map_sets.HERE / "task2.json").read_text())
    monkeypatch.setattr(map_sets, "HERE", tmp_path)
    manifest.cache_clear()

    def ship(change) -> Path:
        data = copy.deepcopy(real)
        change(data)
        path = tmp_path / "task2.json"
        path.write_text(json.dumps(data))
        manifest.cache_clear()
        return path

    yield ship
    manifest.cache_clear()


def _seeds(value):
    return lambda data: data.update(seeds=value)


def _seed(seed, value):
    return lambda data: data["seeds"].update({seed: value})


def _map(seed, e, value):
    return lambda data: data["seeds"][seed].__setitem__(e, value)


@pytest.mark.parametrize(
    "change, problem",
    [
        (_seeds(["948dc078"]), '"seeds" must be an object .*, got list'),
        (_seeds(None), '"seeds" must be an object .*, got NoneType'),
        (lambda data: data["seeds"].pop("1000"), r'"seeds" lacks the frozen seed\(s\) \[1000\]'),
        (_seed("0", []), "seed 0 must be a list of 1000 map hashes, got 0 hashes"),
        (_seed("0", "948dc078"), "seed 0 must be a list of 1000 map hashes, got str"),
        (lambda data: data["seeds"]["1"].pop(), "seed 1 must be a list of 1000 map hashes, got 999 hashes"),
        (_map("2", 7, 12345), "map 7 of seed 2 is not a map hash .*: 12345"),
        (_map("0", 0, None), "map 0 of seed 0 is not a map hash .*: None"),
        (_map("0", 3, "xyz"), "map 3 of seed 0 is not a map hash .*: 'xyz'"),
        (_seed("x", ["948dc078"] * 1000), "seed 'x' of \"seeds\" is not a non-negative int"),
    ],
)
def test_a_tampered_manifest_is_refused_naming_the_file_and_the_problem(tampered, change, problem):
    path = tampered(change)
    with pytest.raises(ValueError, match=f"manifest {re.escape(str(path))} is malformed: {problem}"):
        check_maps("task2", 0, ["948dc078"])


def test_a_manifest_that_is_not_an_object_is_refused(tampered):
    path = tampered(lambda data: None)
    path.write_text("[1, 2]")
    with pytest.raises(ValueError, match=f"{re.escape(str(path))} is not a catmip-map-set-v1 manifest"):
        manifest("task2")


def test_nothing_compared_is_never_verified():
    report = check_maps("task2", 0, [])
    assert (report.status, report.verified_episodes) == ("not frozen", 0)
