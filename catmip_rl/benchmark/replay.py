"""Replaying an entry (``catmip leaderboard --replay K``): its first K maps of every setting and training
run are played again from the files the entry names, and their rescue ticks must be the entry's.

The env is deterministic per seed, and a world's episode depends on its own map and decisions only
(planners draw from one stream per world and episode, :class:`catmip_env.planners.core.Planner`), so K
maps played alone give the ticks those maps got among the entry's 1,000. Each run is rebuilt from its
``spec`` (:func:`~catmip_rl.benchmark.entry.method_spec`); every file it names (a model, a policy
file, a policy's weights) must hold the bytes its SHA-256 says. Torch plays on one thread, as the suite's
jobs do. A ``py:`` policy is played in a worker process that holds no engine
(:mod:`~catmip_rl.evaluation.sandbox`, ``evaluate(..., isolated=True)``), so that it cannot reach the
world it is scored in.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from catmip_env.map_sets import SPLITS
from catmip_rl.benchmark.entry import SETTINGS
from catmip_rl.benchmark.entry_check import EntryError
from catmip_rl.evaluation.evaluate import evaluate, progress_bar
from catmip_rl.evaluation.methods import parse_method
from catmip_rl.store.shipped import file_sha256

__all__ = ["replay_entry", "check_files", "run_files"]


def run_files(run: dict[str, Any]) -> list[dict[str, str]]:
    """The files one training run of an entry plays, each ``{"file", "sha256"}``: its ``source`` (the model
    or the policy file) and the ``files`` its policy names (its weights); a planner's run plays none."""
    return [f for f in [run.get("source"), *(run.get("files") or [])] if f is not None]


def check_files(entry: dict[str, Any], k: int) -> None:
    """EntryError unless every file run ``k`` of ``entry`` names is here with its recorded SHA-256."""
    for f in run_files(entry["runs"][k]):
        path = Path(f["file"])
        where = f"entry {entry['path']}: run {k} plays {path}"
        if not path.is_file():
            raise EntryError(f"{where}, which is not here (replay from the folder its paths start in)")
        if file_sha256(path) != f["sha256"]:
            raise EntryError(f"{where}, whose SHA-256 differs from the entry's: not the file it played")


def _ticks(episodes: list[dict[str, Any]]) -> list[int]:
    return [-1 if e.get("rescue_tick") is None else int(e["rescue_tick"]) for e in episodes]


def replay_entry(entry: dict[str, Any], maps: int, progress: bool = False) -> int:
    """Play maps 0 .. ``maps``-1 of every setting and training run of a checked ``entry`` (from
    :func:`~catmip_rl.benchmark.entry_check.load_entries`) and compare their rescue ticks with the
    entry's; returns ``maps``. :class:`EntryError` in one line at the first file that is not the one
    played or the first map whose tick differs."""
    from catmip_rl.evaluation.workers import torch_threads

    maps = min(maps, entry["episodes"])
    seed = SPLITS[entry["split"]]
    runs = entry["runs"]
    bar = progress_bar(len(runs) * len(SETTINGS), f"replay {entry['method']}", progress, unit="run")
    torch_threads(1)
    for k, run in enumerate(runs):
        check_files(entry, k)
        try:
            method = parse_method(f"{entry['method']}={run['spec']}")
        except ValueError as err:
            raise EntryError(f"entry {entry['path']}: run {k}'s spec {run['spec']!r}: {err}") from None
        for st in SETTINGS:
            result = evaluate(method, st, maps, seed, sampled_too=False, isolated=method.kind == "py")
            got, want = _ticks(result.episodes), entry["settings"][st.label]["rescue_tick"][k][:maps]
            bad = next((m for m in range(maps) if got[m] != want[m]), None)
            if bad is not None:
                raise EntryError(
                    f"entry {entry['path']} refused: replaying map {bad} of {st.label} (run {k}) gave rescue "
                    f"tick {got[bad]}, the entry says {want[bad]}"
                )
            if bar is not None:
                bar.update(1)
    if bar is not None:
        bar.close()
    return maps
