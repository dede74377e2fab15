"""The frozen map sets: this installation generates the shipped maps, and other maps are refused."""

from __future__ import annotations

import pytest

from catmip_env.map_sets import (
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
