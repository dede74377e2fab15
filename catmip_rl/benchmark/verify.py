"""Verifying a board (``catmip leaderboard --replay K --fresh M``): every training run of every entry is
played again, on K of its own maps a setting (chosen at verification time, :mod:`.replay`) and on M fresh
maps a setting that nobody could have played before (a map set whose seed is drawn from the operating
system's entropy now, :func:`draw_seed`), and judged by the fresh-map rule (:mod:`.fresh_rule`).

Before anything is played, entries are compared with each other from their recorded ticks: an entry
whose ticks equal another's on at least :data:`PLAYS_AS` of the maps of every setting is refused as
"plays as X" (the later one; a renamed copy), and so is an entry two of whose runs do (a run listed
twice). While a ``py:`` policy plays (isolated), its worker counts what it calls of the project: one
that builds or resets a world, reads a map set or generates maps is refused; one that runs a planner
is shown as a hybrid, whatever class its entry states.

The outcome is a record (:func:`verify_board`, ``verification.json`` beside the page): the seed, which
maps were replayed, each run's fresh-map numbers, each entry's outcome -- verified, refused (one line),
or "cannot verify here" (this machine computes ticks otherwise than the entry's) -- the package versions,
the machine and the date. The page renders from it; ``--seed S`` repeats a check exactly.
"""

from __future__ import annotations

import datetime
import multiprocessing
import os
import platform
import secrets
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from typing import Any

import numpy as np

from catmip_env.maps.map_sets import FROZEN_SEEDS, MapSetMismatch
from catmip_env.runtime.machine import machine_info
from catmip_rl.benchmark import fresh_rule
from catmip_rl.benchmark.entry import SETTINGS, machine_of, package_versions, rescued_by_100
from catmip_rl.benchmark.entry_check import EntryError
from catmip_rl.benchmark.replay import (
    CannotVerify,
    check_files,
    plays_isolated,
    replay_indices,
    replay_run,
    run_method,
    ticks_of,
)
from catmip_rl.benchmark.runner import Runner
from catmip_rl.benchmark.shipping import run_bundle
from catmip_rl.evaluation.evaluate import evaluate, progress_bar
from catmip_rl.evaluation.user_policy import PolicyError
from catmip_rl.store.shipped import file_sha256

__all__ = ["RECORD", "RECORD_FORMAT", "PLAYS_AS", "draw_seed", "verify_board", "twin_refusals", "WORLD_CALLS"]

RECORD = "verification.json"
RECORD_FORMAT = "catmip-verification-v1"
PLAYS_AS = 0.95  # equal ticks on this share of the maps of every setting: the same policy
WORLD_CALLS = ("worlds", "map_sets", "mapgen")  # what a policy may not call while it plays
PLANNER_CALLS = "planner_decisions"


def draw_seed() -> int:
    """A verification seed from the operating system's entropy (63 bits), never a frozen map set's."""
    while True:
        seed = secrets.randbits(63)
        if seed not in FROZEN_SEEDS:
            return seed


def _ticks(entry: dict[str, Any]) -> dict[str, np.ndarray]:
    return {st.label: np.asarray(entry["settings"][st.label]["rescue_tick"], np.int64) for st in SETTINGS}


def _twin(a: dict[str, np.ndarray], b: dict[str, np.ndarray], i: int, j: int) -> bool:
    """Run ``i`` of ticks ``a`` and run ``j`` of ``b`` equal on at least :data:`PLAYS_AS` of the maps of
    every setting (on the maps both played)."""
    for label in a:
        n = min(a[label].shape[1], b[label].shape[1])
        if (a[label][i, :n] == b[label][j, :n]).mean() < PLAYS_AS:
            return False
    return True


def twin_refusals(entries: list[dict[str, Any]], known: frozenset[str] = frozenset()) -> dict[str, str]:
    """Entries refused from their recorded ticks alone, by method: a run listed twice (two runs of the
    entry equal, :func:`_twin`), and an entry a run of which plays as a run of an earlier entry: "plays
    as X". Earlier: an entry of ``known`` (verified by the last check, as the same file) before any
    other, then by ``created`` and file name (what an entry says of itself counts last)."""
    refused: dict[str, str] = {}
    ticks = {e["method"]: _ticks(e) for e in entries}
    for e in entries:
        t, runs = ticks[e["method"]], len(e["runs"])
        pair = next(((i, j) for i in range(runs) for j in range(i + 1, runs) if _twin(t, t, i, j)), None)
        if pair is not None:
            refused[e["method"]] = (
                f"runs {pair[0]} and {pair[1]} give the same ticks on ≥ {PLAYS_AS:.0%} of the maps of every "
                "setting: a run listed twice (each training run once)"
            )
    order = sorted(
        entries, key=lambda e: (e["method"] not in known, str(e.get("created")), e.get("file", e["method"]))
    )
    for later_at, e in enumerate(order):
        if e["method"] in refused:
            continue
        for earlier in order[:later_at]:
            a, b = ticks[e["method"]], ticks[earlier["method"]]
            if any(_twin(a, b, i, j) for i in range(len(e["runs"])) for j in range(len(earlier["runs"]))):
                refused[e["method"]] = (
                    f"plays as {earlier['method']}: its ticks equal that entry's on ≥ {PLAYS_AS:.0%} of the "
                    "maps of every setting (a renamed copy)"
                )
                break
    return refused


def _fresh_wins(method, st, seed: int, maps: range, horizon: int, out: dict[str, Any]) -> int:
    """How many of fresh ``maps`` (episode indices of ``seed``) ``method`` rescues by tick 100 in setting
    ``st``; what its policy called is added to ``out["calls"]``."""
    res = evaluate(
        method, st, seed=seed, sampled_too=False, isolated=plays_isolated(method), episode_indices=maps
    )
    _add(out["calls"], res.summary.get("policy_calls"))
    return int(rescued_by_100(ticks_of(res.episodes), horizon).sum())


def _add(total: dict[str, int], calls: dict[str, int] | None) -> None:
    for key, value in (calls or {}).items():
        total[key] = total.get(key, 0) + int(value)


def verify_run(entry: dict[str, Any], k: int, seed: int, replay: int | None, fresh: int) -> dict[str, Any]:
    """Verify run ``k`` of ``entry`` (a worker's job): its files, its replayed maps, its fresh maps (and
    their second stage, :func:`~catmip_rl.benchmark.fresh_rule.suspicious`), judged. Returns the run's
    record; ``error`` (one line) and ``kind`` ("refused" or "cannot verify here") where it failed."""
    from catmip_rl.evaluation.workers import torch_threads

    torch_threads(1)
    out: dict[str, Any] = {"run": k, "replayed": {}, "calls": {}}
    try:
        check_files(entry, k)
        method = run_method(entry, k)
        first, claimed, horizons = {}, {}, {}
        for st in SETTINGS:
            if replay != 0:  # 0: the fresh maps only
                picks = replay_indices(seed, entry["method"], k, st.label, entry["episodes"], replay)
                _ticks_played, calls = replay_run(entry, k, st, picks)
                out["replayed"][st.label] = picks
                _add(out["calls"], calls)
            stated = entry["settings"][st.label]
            horizons[st.label] = int(stated["horizon"])
            claimed[st.label] = float(rescued_by_100(stated["rescue_tick"][k], horizons[st.label]).mean())
            if fresh:
                first[st.label] = _fresh_wins(method, st, seed, range(fresh), horizons[st.label], out)
        if fresh:
            more = range(fresh, (1 + fresh_rule.SECOND_STAGE) * fresh)
            late = fresh_rule.suspicious(claimed, entry["episodes"], first, fresh)
            second = {
                st.label: (_fresh_wins(method, st, seed, more, horizons[st.label], out), len(more))
                for st in SETTINGS
                if st.label in late
            }
            verdict = fresh_rule.judge_run(claimed, entry["episodes"], first, fresh, second)
            out |= {"fresh": verdict.settings, "pooled": verdict.pooled}
            if verdict.refused:
                out |= {"error": f"run {k} on fresh maps: {verdict.reason}", "kind": "refused"}
    except CannotVerify as err:
        out |= {"error": _reason(err, entry), "kind": "cannot verify here"}
    except MapSetMismatch as err:
        out |= {"error": f"cannot verify here: {_reason(err, entry)}", "kind": "cannot verify here"}
    except (EntryError, PolicyError, ValueError) as err:
        out |= {"error": _reason(err, entry), "kind": "refused"}
    return out


def _reason(err: Exception, entry: dict[str, Any]) -> str:
    """An error as one line of the page, under the entry's file name: without "entry PATH refused: "."""
    text = " ".join(str(err).split())
    for head in (f"entry {entry['path']} refused: ", f"entry {entry['path']}: "):
        if text.startswith(head):
            return text[len(head) :]
    return text


def _entry_outcome(entry: dict[str, Any], runs: list[dict[str, Any]], stated: str) -> dict[str, Any]:
    calls: dict[str, int] = {}
    for r in runs:
        _add(calls, r["calls"])
    record: dict[str, Any] = {
        "outcome": "verified",
        "reason": "",
        "class": stated,
        "class_note": "",
        "runs": runs,
    }
    failed = next((r for r in runs if r.get("kind") == "refused"), None) or next(
        (r for r in runs if "error" in r), None
    )
    world = {key: calls[key] for key in WORLD_CALLS if calls.get(key)}
    if world:
        said = ", ".join(f"{key} {n}" for key, n in world.items())
        record |= {
            "outcome": "refused",
            "reason": f"its policy builds, resets or reads worlds while it plays ({said})",
        }
    elif failed is not None:
        record |= {"outcome": failed["kind"], "reason": failed["error"]}
    if calls.get(PLANNER_CALLS) and stated == "learned":
        record |= {
            "class": "hybrid",
            "class_note": "shown as hybrid: its policy ran a planner while it played "
            f"({calls[PLANNER_CALLS]:,} planner decisions); a learned entry plays from its own observations",
        }
    return record


def _pool(jobs: int) -> ProcessPoolExecutor:
    from catmip_rl.evaluation.workers import die_with_parent

    spawn = multiprocessing.get_context("spawn")
    return ProcessPoolExecutor(jobs, mp_context=spawn, initializer=die_with_parent, initargs=(os.getpid(),))


def _play_all(todo: dict, results: dict, plan: tuple, jobs: int, bar) -> None:
    """:func:`verify_run` of every job of ``todo`` (key -> (entry, run)) into ``results``, in worker
    processes, so that a policy that kills its evaluator ends one run's check, not the command. After a
    second broken pool the runs left are played one at a time, each in a pool of its own: a run that
    breaks its own pool is refused in one line."""
    pending, breaks = dict(todo), 0
    while pending:
        alone = breaks >= 2
        batch = dict([next(iter(pending.items()))]) if alone else dict(pending)
        broke = _play_batch(batch, results, plan, 1 if alone else max(1, min(jobs, len(batch))), bar)
        for key in batch:
            if key in results:
                del pending[key]
        if broke and alone:
            ((key, _job),) = batch.items()
            results[key] = _lost(key[1])
            del pending[key]
            if bar is not None:
                bar.update(1)
        breaks += broke


def _play_batch(batch: dict, results: dict, plan: tuple, size: int, bar) -> bool:
    """Play ``batch`` on a pool of ``size`` processes into ``results``; True if the pool broke."""
    pool = _pool(size)
    futures = {pool.submit(verify_run, *job, *plan): key for key, job in batch.items()}
    try:
        for done in as_completed(futures):  # the bar counts runs as they end, in any order
            results[futures[done]] = done.result()
            if bar is not None:
                bar.update(1)
    except BrokenProcessPool:
        return True
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    return False


def _on_ray(todo: dict, plan: tuple, runner: Runner, progress: bool) -> tuple[dict, list[dict[str, Any]]]:
    """:func:`verify_run` of every job of ``todo`` (key -> (entry, run)) as Ray tasks, each run's files
    (and its policy's folder) shipped by content from this folder, the clone's root; a run whose worker
    was lost past Ray's retries is refused in one line, as on the local pool, and so is a run whose files
    cannot be sent. Also every machine that played a run, once each."""
    results, items, keys = {}, [], []
    for key, (entry, k) in todo.items():
        try:
            items.append((entry, k, plan, run_bundle(entry, k)))
            keys.append(key)
        except (ValueError, OSError) as err:
            results[key] = _lost(k) | {"error": f"run {k}: its files cannot be sent to the workers: {err}"}
    out = runner.map(
        _verify_shipped,
        items,
        progress=progress,
        desc="verify",
        unit="runs",
        on_error=lambda i, _e: (_lost(keys[i][1]), None),
    )
    machines: list[dict[str, Any]] = []
    for key, (result, machine) in zip(keys, out):
        results[key] = result
        if machine is not None and machine not in machines:
            machines.append(machine)
    return results, machines


def _verify_shipped(item: tuple) -> dict[str, Any]:
    """A Ray task: :func:`verify_run` in a folder of its own where its files were unpacked (their paths
    start there, as in the clone), and the machine that played it."""
    from catmip_rl.benchmark.shipping import unpacked

    entry, k, plan, bundle = item
    machine = machine_info(host=platform.node())
    if bundle is None:
        return verify_run(entry, k, *plan), machine
    here = os.getcwd()
    with unpacked(bundle) as folder:
        os.chdir(folder)
        try:
            return verify_run(entry, k, *plan), machine
        finally:
            os.chdir(here)


def _lost(k: int) -> dict[str, Any]:
    """The record of run ``k`` whose process was killed while its policy played."""
    return {
        "run": k,
        "replayed": {},
        "calls": {},
        "kind": "refused",
        "error": f"run {k}: the process that played it was killed while its policy played "
        "(a policy never ends or signals the process that evaluates it)",
    }


def verify_board(
    entries: list[dict[str, Any]],
    replay: int | None,
    fresh: int,
    seed: int | None = None,
    jobs: int = 1,
    progress: bool = False,
    known: frozenset[str] = frozenset(),
    backend: str = "local",
    ray_address: str | None = None,
) -> dict[str, Any]:
    """Verify every entry (checked, :func:`~catmip_rl.benchmark.entry_check.load_entries`): ``replay``
    maps a setting and run (None: all), ``fresh`` fresh maps a setting (0: none), from ``seed`` (None: drawn
    now, :func:`draw_seed`), on ``jobs`` processes (``backend`` "ray": Ray tasks, each run's files
    shipped by content, :func:`_on_ray`); ``known``: the methods the last check verified (the originals
    of any copy, :func:`twin_refusals`). Returns the record (see the module's docstring)."""
    from catmip_rl.evaluation.bounds import not_dumpable

    not_dumpable()  # the seed of the fresh maps is in this process: no policy's to read
    seed = draw_seed() if seed is None else int(seed)
    refused = twin_refusals(entries, known)
    tasks = [(e, k) for e in entries if e["method"] not in refused for k in range(len(e["runs"]))]
    plain = [{key: v for key, v in e.items() if key != "checked"} for e, _k in tasks]
    jobs_by_key = {(e["method"], k): (p, k) for p, (e, k) in zip(plain, tasks)}
    results: dict[tuple[str, int], dict[str, Any]] = {}
    played_on = [machine_info(host=platform.node())]  # the machines that replayed runs: here, or Ray's
    if backend == "ray":
        runner = Runner("ray", jobs, ray_address)
        results, played_on = _on_ray(jobs_by_key, (seed, replay, fresh), runner, progress)
    else:
        bar = progress_bar(len(tasks), "verify", progress, unit="run", leave=True)
        try:
            _play_all(jobs_by_key, results, (seed, replay, fresh), jobs, bar)
        finally:
            if bar is not None:
                bar.close()
    record_entries = {}
    for e in entries:
        head = {"file": e["file"], "sha256": file_sha256(e["path"])}
        if e["method"] in refused:
            record_entries[e["method"]] = head | {
                "outcome": "refused",
                "reason": refused[e["method"]],
                "class": e["class"],
                "class_note": "",
                "runs": [],
            }
            continue
        runs_done = [results[(e["method"], k)] for k in range(len(e["runs"]))]
        record_entries[e["method"]] = head | _entry_outcome(e, runs_done, e["class"])
    return {
        "format": RECORD_FORMAT,
        "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "versions": package_versions(),
        "machine": machine_of(played_on, "the runs were replayed"),
        "played_on": played_on,
        "seed": seed,
        "replay": "all" if replay is None else replay,
        "fresh": fresh,
        "rule": {
            "fresh_maps": fresh,
            "second_stage": fresh_rule.SECOND_STAGE,
            "z_suspect": fresh_rule.Z_SUSPECT,
            "z_setting": fresh_rule.Z_SETTING,
            "z_pooled": fresh_rule.Z_POOLED,
            "plays_as": PLAYS_AS,
        },
        "entries": record_entries,
    }
