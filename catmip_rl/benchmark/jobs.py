"""Evaluation runs as jobs: a grid of (setting, method, training run) evaluations, each played in map
chunks by a job runner (:mod:`~catmip_rl.benchmark.runner`: a local pool or Ray), merged in map order
and written to its own folder (:mod:`~catmip_rl.evaluation.evaluate`'s files); each returns what a
figure or a suite entry is made of. ``catmip bench paper`` (:mod:`~catmip_rl.benchmark.paper`) and
``catmip bench suite`` (:mod:`~catmip_rl.benchmark.suite`) run their grids through :func:`map_jobs`."""

from __future__ import annotations

import csv
import json
import os
import platform
from contextlib import nullcontext
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from catmip_env.engines.events import EventEngine
from catmip_env.play import WorldNotSupported, plays_one_world_at_a_time
from catmip_env.runtime.machine import machine_info
from catmip_rl.benchmark.resume_check import check_resumed, read_summary
from catmip_rl.benchmark.runner import Runner
from catmip_rl.benchmark.shipping import Bundle, bundle_for, importable, played_from, restored, unpacked
from catmip_rl.evaluation.evaluate import EvalSetting, evaluate, result_of
from catmip_rl.evaluation.methods import PLAY_OPTIONS, Method, changed_files, make_policy, method_source
from catmip_rl.evaluation.played import Played, merge_played
from catmip_rl.evaluation.workers import torch_threads

__all__ = [
    "Job",
    "Chunk",
    "run_one",
    "map_jobs",
    "play_chunk",
    "chunks_of",
    "check_methods",
    "run_dir",
    "default_threads",
]

CHUNK_MAPS = 100
"""Maps a chunk: the unit a runner sends to a worker (a Task-3 setting of the suite is 10 chunks)."""


@dataclass(frozen=True)
class Job:
    """One evaluation of a grid: ``method`` on ``episodes`` maps of ``seed`` in ``setting``, its files
    written to ``out`` with ``threads`` torch threads. ``sampled``: a learned policy plays the maps
    again with sampled actions (its ``sampled_*`` numbers; ``evaluate``'s ``sampled_too``).
    ``resume``: a folder that already holds this job's complete results (their ``summary.json``: the
    same method, file, setting, seed and maps) is read back instead of played again; other results
    there are an error."""

    method: Method
    setting: EvalSetting
    episodes: int
    seed: int
    out: str
    threads: int = 1
    allow_other_maps: bool = False
    resume: bool = False
    sampled: bool = True


def _done(job: Job) -> dict[str, Any] | None:
    """The summary of ``job``'s results already in its folder, or None if it has none; ValueError if the
    folder holds another run's (``summary.json`` is written last: a folder with one is complete)."""
    if not job.resume or not (Path(job.out) / "summary.json").is_file():
        return None
    summary = read_summary(Path(job.out))
    want = {
        "method": job.method.name,
        "method_kind": job.method.kind,
        "target": job.method.target,
        "synchronous": job.method.synchronous,
        "label": job.setting.label,
        "seed": job.seed,
        "episodes": job.episodes,
        "source": method_source(job.method),
    }
    want |= {key: getattr(job.method, key) for key, _ in PLAY_OPTIONS}  # how an AMAT played
    found = {key: False for key, _ in PLAY_OPTIONS} | summary  # an older summary lacks newer options
    differs = [k for k, v in want.items() if found.get(k) != v]
    source = found.get("source") if isinstance(found.get("source"), dict) else {}
    if differs == ["source"] and want["source"] and source.get("file") == want["source"]["file"]:
        raise ValueError(  # the same file, changed since: one readable line, not two dicts
            f"{job.out} holds results played before {want['source']['file']} changed (its SHA-256 "
            f"{str(source.get('sha256'))[:12]}... is now {want['source']['sha256'][:12]}...): give a new "
            "output folder"
        )
    if differs:
        raise ValueError(
            f"{job.out} holds other results ({', '.join(f'{k} {_said(found.get(k))}' for k in differs)}, "
            f"not {', '.join(_said(want[k]) for k in differs)}): give a new output folder"
        )
    changed = changed_files(summary.get("policy_files"))
    if changed:
        raise ValueError(
            f"{job.out} holds results played before {changed[0]} changed (its SHA-256 differs): "
            "give a new output folder"
        )
    check_resumed(Path(job.out), job.setting, job.seed, job.episodes, job.method.name)  # all it can recompute
    return summary


def _said(value: Any) -> str:
    """A recorded value in a message: a source as its file and SHA-256's start, anything else its repr."""
    if isinstance(value, dict) and set(value) == {"file", "sha256"}:
        return f"{value['file']} (SHA-256 {str(value['sha256'])[:12]}...)"
    return repr(value)


def run_one(job: Job) -> dict[str, Any]:
    """Play ``job`` in this process (or read it back, :attr:`Job.resume`) and write its folder; returns
    what :func:`map_jobs` returns for it."""
    return map_jobs([job], 1, False, "")[0]


def _read_back(job: Job, summary: dict[str, Any]) -> dict[str, Any]:
    """A complete run's results read back from its folder (:func:`_done` found them)."""
    episodes = json.loads((Path(job.out) / "episodes.json").read_text())
    with open(Path(job.out) / "curve.csv") as f:
        rows = list(csv.DictReader(f))
    curve = [float(r["success_rate"]) for r in rows]
    sampled = [float(r["sampled_success_rate"]) for r in rows] if "sampled_success_rate" in rows[0] else None
    return _run_results(job, summary, episodes, curve, sampled, summary.get("played_on") or [])


def _run_results(job, summary, episodes, curve, sampled, machines) -> dict[str, Any]:
    """A run's ``out``, ``summary``, ``curve`` / ``sampled_curve`` (success rate vs tick), per-episode
    ``ticks`` (rescue ticks, NaN where not rescued, of the policy and of its sampled pass), ``maps`` (the
    maps played, in order: an entry's digest) and ``machines`` (what played its chunks: none when read
    back)."""
    ticks = {
        key: [np.nan if e.get(key) is None else e[key] for e in episodes]
        for key in ("rescue_tick", "sampled_rescue_tick")
        if key in episodes[0]
    }
    maps = [e["map_hash"] for e in episodes]
    return {
        "out": job.out,
        "summary": summary,
        "curve": curve,
        "sampled_curve": sampled,
        "ticks": ticks,
        "maps": maps,
        "machines": machines,
    }


@dataclass(frozen=True)
class Chunk:
    """Maps ``first`` .. ``first + count - 1`` of a job, and the files that play its method where the
    driver's disk is not (:mod:`~catmip_rl.benchmark.shipping`; None: played where they lie)."""

    job: Job
    first: int
    count: int
    bundle: Bundle | None = None


def chunks_of(job: Job, size: int | None = None) -> list[tuple[int, int]]:
    """A job's maps in chunks of ``size`` (default :data:`CHUNK_MAPS`; the last one shorter), as (first,
    count): the same split on every back end."""
    size = size or CHUNK_MAPS
    return [(first, min(size, job.episodes - first)) for first in range(0, job.episodes, size)]


def play_chunk(chunk: Chunk) -> tuple[Played, dict[str, Any]]:
    """Play one chunk (wherever the runner sent it): its unsummarised play, with the driver's paths, and
    the machine that played it."""
    job, method = chunk.job, chunk.job.method
    torch_threads(job.threads)
    indices = np.arange(chunk.first, chunk.first + chunk.count)
    play = {"seed": job.seed, "sampled_too": job.sampled, "allow_other_maps": job.allow_other_maps}
    if chunk.bundle is None:
        played = evaluate(method, job.setting, episode_indices=indices, chunk=True, **play)
    else:
        with unpacked(chunk.bundle) as folder:
            there = played_from(chunk.bundle, method, folder)
            with importable(folder, chunk.bundle) if not chunk.bundle.entry else nullcontext():
                played = evaluate(there, job.setting, episode_indices=indices, chunk=True, **play)
        played = replace(played, method=method, info=restored(played.info, chunk.bundle, folder))
    return played, machine_info(host=platform.node())


def map_jobs(
    tasks: list[Job],
    jobs: int,
    progress: bool,
    desc: str,
    backend: str = "local",
    ray_address: str | None = None,
) -> list[dict[str, Any]]:
    """Every task's results (:func:`_run_results`), in order: a complete run read back (:attr:`Job.resume`),
    every other run's maps played in chunks of :data:`CHUNK_MAPS` by a :class:`~catmip_rl.benchmark.
    runner.Runner` (``backend``, ``jobs`` workers, ``ray_address``) and its folder written as soon as its
    last chunk is in (an interrupted grid resumes from the runs written). The bar counts chunks weighted
    by their size (:func:`run_cost`). The files do not depend on the back end or the workers."""
    runner = Runner(backend, max(int(jobs), 1), ray_address)
    results: list[dict[str, Any] | None] = []
    for job in tasks:
        _no_link(Path(job.out))
        summary = _done(job)
        results.append(None if summary is None else _read_back(job, summary))
    ship = runner.backend == "ray"  # a worker may be another machine: the files go by content
    bundles = {}
    chunks, owner = [], []
    for i, job in enumerate(tasks):
        if results[i] is not None:
            continue
        if ship and job.method not in bundles:
            bundles[job.method] = bundle_for(job.method)
        for first, count in chunks_of(job):
            chunks.append(Chunk(job, first, count, bundles.get(job.method)))
            owner.append(i)
    parts: dict[int, dict[int, tuple[Played, dict[str, Any]]]] = {i: {} for i in set(owner)}
    counts = {i: owner.count(i) for i in parts}  # each run's chunks

    def on_done(k: int, part: tuple[Played, dict[str, Any]]) -> None:
        i = owner[k]
        parts[i][k] = part
        if len(parts[i]) == counts[i]:  # the run's last chunk: merge in map order, write it
            ordered = [parts[i][j] for j in sorted(parts[i])]
            result = result_of(merge_played([p for p, _ in ordered]))
            machines = [m for j, (_, m) in enumerate(ordered) if m not in [n for _, n in ordered[:j]]]
            result.summary["played_on"] = machines  # every machine that played a chunk
            result.write(tasks[i].out)
            sampled = None if result.sampled_curve is None else result.sampled_curve.tolist()
            results[i] = _run_results(
                tasks[i], result.summary, result.episodes, result.curve.tolist(), sampled, machines
            )
            parts[i].clear()

    weights = [run_cost(replace(c.job, episodes=c.count)) for c in chunks]
    shared = (_without_bundle, _with_bundle)  # on Ray, a method's files go to the object store once
    runner.map(play_chunk, chunks, weights, on_done, progress, desc, unit="chunks", shared=shared)
    return results


def _without_bundle(chunk: Chunk) -> tuple[Chunk, Bundle | None]:
    return replace(chunk, bundle=None), chunk.bundle


def _with_bundle(chunk: Chunk, bundle: Bundle | None) -> Chunk:
    return replace(chunk, bundle=bundle)


def _no_link(folder: Path) -> None:
    """ValueError if a run's folder, or one of the two grid folders above it (``runs/LABEL/NAME[/runK]``),
    is a symbolic link: a grid reads and writes its own folders, never through a link to elsewhere."""
    for path in (folder, folder.parent, folder.parent.parent):
        if path.is_symlink():
            raise ValueError(f"{path} is a symbolic link: a grid reads and writes only its own folders")


def run_cost(job: Job) -> float:
    """A run's size in Task-2 runs of as many maps: maps × robots × cells × horizon (what a tick of the
    batched world costs, over the episode), relative to Task 2's."""
    cfg = job.setting.env_config()
    h, w = cfg.map_shape
    return job.episodes * cfg.num_robots * h * w * cfg.horizon_ticks / (3 * 400 * 400)


def check_methods(
    groups: list[list[Method]], panels: list, seed: int
) -> tuple[dict[tuple[str, str], list[Method]], dict[tuple[str, str], str]]:
    """Load every AMAT checkpoint and build every ``py:`` policy for every panel, letting it decide once,
    before any run starts (an unreadable file or a broken policy raises here). Returns, per (panel,
    method), the method's runs that can play the panel, and the pairs none of its runs can play
    with the reason (:class:`~catmip_env.play.WorldNotSupported`, e.g. a CNN built for another map
    size): a method of runs trained on different tasks plays each panel with the runs trained for its
    world."""
    plays: dict[tuple[str, str], list[Method]] = {}
    not_played: dict[tuple[str, str], str] = {}
    for runs in groups:
        for m in runs:
            if m.kind == "amat":
                from catmip_rl.store.checkpoint import load_model  # torch: only where a model is played

                load_model(m.target)
        for panel, setting in panels:
            able, why = [], ""
            for m in runs:
                try:
                    if m.kind == "py":
                        _first_decision(m, setting.env_config(None, m.synchronous), seed)
                    able.append(m)
                except WorldNotSupported as exc:
                    why = str(exc)
            if able:
                plays[(panel, runs[0].name)] = able
            else:
                not_played[(panel, runs[0].name)] = why
    return plays, not_played


def _first_decision(method: Method, env_config, seed: int) -> None:
    """Build a ``py:`` policy and let it decide once in a fresh world of the setting, called as an
    evaluation calls it (the :class:`~catmip_env.play.Policy` protocol: ``start_episodes`` first where
    it has one, ``reset()`` before the episode of a policy that plays one world at a time): a factory or
    an ``act`` that fails (a :class:`~catmip_rl.evaluation.user_policy.PolicyError`) fails here, before
    any run is played, not after the baselines."""
    from catmip_rl.evaluation.sandbox import close_policy

    policy, goal_mode, _needs = make_policy(method, env_config, seed)
    try:
        engine = EventEngine(env_config, num_worlds=1, seed=seed, goal_mode=goal_mode)
        engine.reset()
        if hasattr(policy, "start_episodes"):
            policy.start_episodes(engine.num_worlds, engine.num_robots)
        if plays_one_world_at_a_time(policy):
            policy.reset()
        policy.act(engine)
    finally:
        close_policy(policy)


def default_threads(jobs: int, threads: int | None) -> int:
    """Torch threads of each job: ``threads`` if given, else the machine's CPUs shared among the jobs, at
    most 2 (2 for one job on 2 CPUs, 1 for two): jobs x threads never more than the CPUs (the engine
    plays on one thread in an evaluation)."""
    return max(1, min(2, available_cpus() // max(int(jobs), 1))) if threads is None else threads


def available_cpus() -> int:
    """The CPUs this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def run_dir(folder: Path, k: int, runs: int) -> Path:
    """The folder of training run ``k`` of a method with ``runs`` runs: ``folder/runK``, or ``folder``."""
    return folder / f"run{k}" if runs > 1 else folder
