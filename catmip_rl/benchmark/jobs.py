"""Evaluation runs as jobs: a grid of (setting, method, training run) evaluations played by a process
pool, each writing its own folder (:mod:`~catmip_rl.evaluation.evaluate`'s files) and returning what a
figure or a suite entry is made of. ``catmip bench paper`` (:mod:`~catmip_rl.benchmark.paper`) and
``catmip bench suite`` (:mod:`~catmip_rl.benchmark.suite`) run their grids through :func:`map_jobs`."""

from __future__ import annotations

import csv
import json
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from catmip_env.events import EventEngine
from catmip_env.play import WorldNotSupported, plays_one_world_at_a_time
from catmip_rl.benchmark.resume_check import check_resumed, read_summary
from catmip_rl.evaluation.evaluate import EvalSetting, evaluate, progress_bar
from catmip_rl.evaluation.methods import PLAY_OPTIONS, Method, changed_files, make_policy, method_source
from catmip_rl.evaluation.workers import die_with_parent, torch_threads

__all__ = ["Job", "run_one", "map_jobs", "check_methods", "run_dir", "default_threads"]


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
    """Play ``job`` (or read it back, :attr:`Job.resume`) and write its folder; returns its ``summary``,
    ``curve`` / ``sampled_curve`` (success rate vs tick) and per-episode ``ticks`` (rescue ticks, NaN
    where not rescued, of the policy and of its sampled pass)."""
    _no_link(Path(job.out))
    summary = _done(job)
    if summary is not None:
        episodes = json.loads((Path(job.out) / "episodes.json").read_text())
        with open(Path(job.out) / "curve.csv") as f:
            rows = list(csv.DictReader(f))
        curve = [float(r["success_rate"]) for r in rows]
        sampled = (
            [float(r["sampled_success_rate"]) for r in rows] if "sampled_success_rate" in rows[0] else None
        )
    else:
        torch_threads(job.threads)
        result = evaluate(
            job.method,
            job.setting,
            job.episodes,
            job.seed,
            sampled_too=job.sampled,
            allow_other_maps=job.allow_other_maps,
        )
        result.write(job.out)
        summary, episodes, curve = result.summary, result.episodes, result.curve.tolist()
        sampled = None if result.sampled_curve is None else result.sampled_curve.tolist()
    ticks = {
        key: [np.nan if e.get(key) is None else e[key] for e in episodes]
        for key in ("rescue_tick", "sampled_rescue_tick")
        if key in episodes[0]
    }
    maps = [e["map_hash"] for e in episodes]  # the maps played, in order (an entry's digest)
    return {
        "out": job.out,
        "summary": summary,
        "curve": curve,
        "sampled_curve": sampled,
        "ticks": ticks,
        "maps": maps,
    }


def _no_link(folder: Path) -> None:
    """ValueError if a run's folder, or one of the two grid folders above it (``runs/LABEL/NAME[/runK]``),
    is a symbolic link: a grid reads and writes its own folders, never through a link to elsewhere."""
    for path in (folder, folder.parent, folder.parent.parent):
        if path.is_symlink():
            raise ValueError(f"{path} is a symbolic link: a grid reads and writes only its own folders")


def map_jobs(tasks: list[Job], jobs: int, progress: bool, desc: str) -> list[dict[str, Any]]:
    """:func:`run_one` of every task, in order, on ``jobs`` processes (spawned: no state shared), with a
    progress bar weighted by each run's size (:func:`run_cost`: a Task-3 run counts about six Task-2
    runs, so the estimate of the time left holds across tasks). Interrupted (Ctrl-C, SIGTERM through
    ``catmip``), the pool's workers are stopped at once and its queues released."""
    bar = progress_bar(len(tasks), desc, progress, unit="run", leave=True)
    weights = [run_cost(t) for t in tasks]
    if bar is not None:
        bar.total = sum(weights)
        bar.bar_format = "{desc}: {percentage:3.0f}%|{bar}| [{elapsed}<{remaining}]"
        bar.set_description_str(f"{desc} 0/{len(tasks)} runs")
    results: list[dict[str, Any]] = []
    with ExitStack() as stack:
        pool = None
        if jobs <= 1:
            runs = map(run_one, tasks)
        else:
            spawn = multiprocessing.get_context("spawn")
            pool = stack.enter_context(
                ProcessPoolExecutor(
                    max_workers=jobs, mp_context=spawn, initializer=die_with_parent, initargs=(os.getpid(),)
                )
            )
            futures = [pool.submit(run_one, t) for t in tasks]  # not pool.map: its iterator cancels them
            runs = (f.result() for f in futures)  # on its way out, which a broken pool then trips over
        try:
            for res, weight in zip(runs, weights):
                results.append(res)
                if bar is not None:
                    bar.set_description_str(f"{desc} {len(results)}/{len(tasks)} runs", refresh=False)
                    bar.update(weight)
        except BaseException:
            if pool is not None:  # stop the workers now: the pool's exit would wait for their runs
                for worker in list((getattr(pool, "_processes", None) or {}).values()):
                    worker.terminate()  # the pool then ends its pending runs as broken, and exits
            raise
    if bar is not None:
        bar.close()
    return results


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
    """Torch threads of each job: ``threads`` if given, else 2 for one job and 1 for several."""
    return (1 if jobs > 1 else 2) if threads is None else threads


def run_dir(folder: Path, k: int, runs: int) -> Path:
    """The folder of training run ``k`` of a method with ``runs`` runs: ``folder/runK``, or ``folder``."""
    return folder / f"run{k}" if runs > 1 else folder
