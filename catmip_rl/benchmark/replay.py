"""Replaying an entry's maps (``catmip leaderboard --replay K``): K maps of every setting and training run,
chosen from the verification's seed (:func:`replay_indices`: drawn from the operating system's entropy
unless given), are played again from the files the entry names, and their rescue ticks must be the
entry's.

The env is deterministic per seed, and a world's episode depends on its own map and decisions only
(planners draw from one stream per world and episode, :class:`catmip_env.planners.core.Planner`), so maps
played alone give the ticks they got among the entry's 1,000. Each run is rebuilt from its ``spec``
(:func:`~catmip_rl.benchmark.entry.method_spec`); every file it names (a model, a policy file, a
policy's weights, the modules its policy imported from its folder) must hold the bytes its SHA-256 says.
Torch plays on one thread, as the suite's jobs do. A ``py:`` policy plays in a worker process that holds
no engine (:mod:`~catmip_rl.evaluation.sandbox`).

A tick that differs is told apart three ways (:func:`replay_run`): the map played again gives another
tick (the policy is not deterministic: its fault, said so); the entry was played where torch or the
map generator may compute otherwise (another package version or CPU: "cannot verify here"); or neither
(the entry states a tick its files do not give: refused).
"""

from __future__ import annotations

import zlib
from pathlib import Path
from typing import Any

import numpy as np

from catmip_env.maps.map_sets import SPLITS
from catmip_env.runtime.machine import machine_info
from catmip_rl.benchmark.entry import SETTINGS, package_versions
from catmip_rl.benchmark.entry_check import EntryError
from catmip_rl.evaluation.evaluate import EvalSetting, evaluate
from catmip_rl.evaluation.methods import Method, parse_method
from catmip_rl.store.shipped import file_sha256

__all__ = [
    "replay_entry",
    "replay_run",
    "replay_indices",
    "check_files",
    "run_files",
    "run_method",
    "CannotVerify",
    "ticks_of",
    "plays_isolated",
]


class CannotVerify(EntryError):
    """This machine cannot tell whether an entry's ticks are right: it computes otherwise than the one
    that played it (another version of a package that decides ticks, or another CPU for torch)."""


def run_files(run: dict[str, Any]) -> list[dict[str, str]]:
    """The files one training run of an entry plays, each ``{"file", "sha256"}``: its ``source`` (the model
    or the policy file) and the ``files`` its policy names (its weights, the modules it imported from its
    own folder); a planner's run plays none."""
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


def run_method(entry: dict[str, Any], k: int) -> Method:
    """Training run ``k`` of ``entry`` as the method that plays it again (EntryError for a bad spec)."""
    try:
        return parse_method(f"{entry['method']}={entry['runs'][k]['spec']}")
    except ValueError as err:
        raise EntryError(
            f"entry {entry['path']}: run {k}'s spec {entry['runs'][k]['spec']!r}: {err}"
        ) from None


def ticks_of(episodes: list[dict[str, Any]]) -> list[int]:
    """Rescue ticks of played episodes, -1 where not rescued (as an entry states them)."""
    return [-1 if e.get("rescue_tick") is None else int(e["rescue_tick"]) for e in episodes]


def replay_indices(seed: int, method: str, k: int, label: str, episodes: int, maps: int | None) -> list[int]:
    """The maps run ``k`` of ``method`` replays in setting ``label``: ``maps`` of the entry's ``episodes``
    (all of them for None), drawn without replacement from a stream keyed by the verification's ``seed``,
    the method, the run and the setting (the same choice wherever the check is repeated with that
    seed), in increasing order."""
    if maps is None or maps >= episodes:
        return list(range(episodes))
    key = [int(seed), zlib.crc32(method.encode()), int(k), zlib.crc32(label.encode())]
    rng = np.random.default_rng(key)
    return sorted(int(x) for x in rng.choice(episodes, size=maps, replace=False))


def plays_isolated(method: Method) -> bool | None:
    """A ``py:`` policy plays in a worker that holds no engine; the project's methods as they are."""
    return True if method.kind == "py" else None


def _plays_torch(method: Method) -> bool:
    return method.kind in ("amat", "py")


def _elsewhere(entry: dict[str, Any], method: Method) -> str:
    """How the machine that played ``entry`` differs from this one in what decides ticks ('' if not):
    the packages that make the maps and the decisions, and, where torch plays, the CPU's capability."""
    here, there = package_versions(), entry.get("versions") or {}
    keys = ["catmip", "numpy", "numba"] + (["torch"] if _plays_torch(method) else [])
    found = [f"{k} {there.get(k)} there, {here.get(k)} here" for k in keys if there.get(k) != here.get(k)]
    if _plays_torch(method):
        mine, theirs = machine_info(), entry.get("machine") or {}
        for key in ("cpu_capability", "native_bf16"):
            if theirs.get(key) != mine.get(key):
                found.append(f"CPU {key} {theirs.get(key)} there, {mine.get(key)} here")
    return "; ".join(found)


def replay_run(
    entry: dict[str, Any], k: int, st: EvalSetting, indices: list[int]
) -> tuple[list[int], dict[str, int] | None]:
    """Play maps ``indices`` of setting ``st`` with run ``k`` of ``entry`` and compare their ticks with the
    entry's; returns the ticks and what the policy called (``policy_calls``, a ``py:`` policy's). A tick
    that differs: the map is played again; :class:`EntryError` if it then gives another tick (the
    policy's non-determinism) or the same one on a machine like the entry's (the entry's tick is not
    what its files give), :class:`CannotVerify` if the machines differ in what decides ticks."""
    method = run_method(entry, k)
    seed = SPLITS[entry["split"]]
    result = evaluate(
        method, st, seed=seed, sampled_too=False, isolated=plays_isolated(method), episode_indices=indices
    )
    got, want = ticks_of(result.episodes), entry["settings"][st.label]["rescue_tick"][k]
    bad = next((j for j, m in enumerate(indices) if got[j] != want[m]), None)
    if bad is None:
        return got, result.summary.get("policy_calls")
    m = indices[bad]
    where = f"map {m} of {st.label} (run {k})"
    again = ticks_of(
        evaluate(
            method, st, seed=seed, sampled_too=False, isolated=plays_isolated(method), episode_indices=[m]
        ).episodes
    )[0]
    if again != got[bad]:
        raise EntryError(
            f"entry {entry['path']} refused: the policy did not reproduce its own ticks on {where}: played "
            f"twice it gave {got[bad]} and {again}; is it seeded from its inputs (the factory's seed, "
            "engine.world.keys), not from the clock or a global stream?"
        )
    elsewhere = _elsewhere(entry, method)
    if elsewhere:
        raise CannotVerify(
            f"entry {entry['path']}: cannot verify here: replaying {where} gave rescue tick {got[bad]}, the "
            f"entry says {want[m]}, and this machine computes otherwise than the one that played it "
            f"({elsewhere})"
        )
    raise EntryError(
        f"entry {entry['path']} refused: replaying {where} gave rescue tick {got[bad]}, the entry says "
        f"{want[m]}"
    )


def replay_entry(entry: dict[str, Any], maps: int | None, seed: int = 0) -> int:
    """Replay ``maps`` maps (None: all) of every setting and training run of a checked ``entry`` (from
    :func:`~catmip_rl.benchmark.entry_check.load_entries`), chosen by ``seed``
    (:func:`replay_indices`); returns the maps replayed a setting and run. Raises as
    :func:`replay_run`, or at the first file that is not the one played."""
    from catmip_rl.evaluation.workers import torch_threads

    torch_threads(1)
    count = 0
    for k in range(len(entry["runs"])):
        check_files(entry, k)
        for st in SETTINGS:
            picks = replay_indices(seed, entry["method"], k, st.label, entry["episodes"], maps)
            replay_run(entry, k, st, picks)
            count = len(picks)
    return count
