"""The benchmark suite: one fixed grid of settings on frozen maps, one entry per method.

    run_suite(["nearest", "mine=py:my_policy.py:make_policy"], split="validation")  # catmip bench suite

**Suite v2** (:data:`SETTINGS`): Tasks 2 and 3 × communication full / σ = 4 / σ = 2 × SLAM noise 0 / 5 %,
each on 1,000 frozen maps of a **split** (:data:`~catmip_env.maps.map_sets.SPLITS`, in
``catmip_env/maps/frozen_maps``): *validation* (seed 1000) for tuning, gates and every choice; *test* (seed
20261201), played once per entry after every choice is frozen: the leaderboard ranks test entries
only. Evaluation activation, the paper's horizon, the longest macro-action 10 ticks. Task 1 is left
out: every planner and AMAT rescue within 0.02 of each other there by tick 100. Weak communication and
SLAM noise are where the planners differ most and where a learned planner can win.

Every (setting, method, training run) is one evaluation (:mod:`~catmip_rl.benchmark.jobs`) in
``OUT/runs/LABEL/NAME[/runK]/``; an interrupted suite resumes: a run whose results are complete is read
back, not played again. Each method then gets an entry, ``OUT/entries/NAME.json``
(:mod:`~catmip_rl.benchmark.entry`); ``catmip leaderboard`` checks entries and ranks them.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from catmip_env.maps.map_sets import SPLITS
from catmip_rl.benchmark.entry import (
    EPISODES,
    SETTINGS,
    SUITE,
    check_split,
    entry_json,
    make_entry,
    method_class,
    method_spec,
)
from catmip_rl.benchmark.entry_check import STATED, check_stated
from catmip_rl.benchmark.estimate import estimate_line
from catmip_rl.benchmark.jobs import Job, check_methods, default_threads, map_jobs, run_dir
from catmip_rl.evaluation.methods import Method, parse_runs
from catmip_rl.evaluation.user_policy import PolicyError
from catmip_rl.store.files import atomic_write_text

__all__ = ["SUITE", "SPLITS", "EPISODES", "SETTINGS", "run_suite"]


def run_suite(
    methods: list[str],
    out: str | Path = "out/suite",
    episodes: int = EPISODES,
    jobs: int = 1,
    threads: int | None = None,
    progress: bool = True,
    code: dict[str, str] | None = None,
    notes: dict[str, str] | None = None,
    split: str = "validation",
    classes: dict[str, str] | None = None,
    chosen_on: dict[str, str] | None = None,
    backend: str = "local",
    ray_address: str | None = None,
) -> list[Path]:
    """Play every method (``NAME=SPEC`` or ``NAME=SPEC,SPEC,...`` for several training runs) on every
    setting of the suite on the maps of ``split`` and write one entry per method, with its ``code``
    link, ``notes``, class (``classes``: a ``py:`` policy's) and ``chosen_on`` (by method name; needed
    on the test split) where given, else those of the entry already in ``out``; returns their paths.
    Resumes an interrupted suite in the same ``out``. A method that cannot play a setting
    (``WorldNotSupported``), an unreadable model or a broken policy raises before anything is played.
    Before the first run it prints how long the runs left will take on this machine, each method timed
    on a few maps of each task (:func:`~catmip_rl.benchmark.estimate.estimate_line`)."""
    seed = check_split(split)
    groups = [parse_runs(m) for m in methods]
    names = [runs[0].name for runs in groups]
    about = {"code": code or {}, "notes": notes or {}, "class": classes or {}, "chosen_on": chosen_on or {}}
    out = Path(out)
    kept = {name: _recorded(out / "entries" / f"{_file_name(name)}.json") for name in names}
    _check_request(groups, names, about, kept, split, episodes)
    panels = [(st.label, st) for st in SETTINGS]
    _plays, not_played = check_methods(groups, panels, seed)
    if not_played:
        (label, name), why = next(iter(not_played.items()))
        raise ValueError(f"method {name} cannot play {label} ({why}): a suite entry needs every setting")
    threads = default_threads(jobs, threads)
    # sampled=False: an entry is the argmax (or the policy's own) actions, one pass
    tasks = [
        Job(
            m,
            st,
            episodes,
            seed,
            str(run_dir(out / "runs" / st.label / m.name, k, len(runs))),
            threads,
            resume=True,
            sampled=False,
        )
        for runs in groups
        for k, m in enumerate(runs)
        for st in SETTINGS
    ]
    line = estimate_line(tasks, jobs)  # before the first run: how long the runs left take here
    if line is not None:
        print(line, flush=True)
    try:
        results = iter(map_jobs(tasks, jobs, progress, f"suite {SUITE}", backend, ray_address))
    except PolicyError as err:  # a policy that broke mid-suite: what was played is kept
        finished = sum(1 for _ in (out / "runs").rglob("run.json"))
        raise PolicyError(
            f"{err}; the {finished} finished run(s) are kept in {out / 'runs'}: fix the policy and run the "
            "same command with --resume to play only the rest"
        ) from None
    paths = []
    for runs in groups:
        per_setting: dict[str, list[dict[str, Any]]] = {st.label: [] for st in SETTINGS}
        for _m in runs:
            for st in SETTINGS:
                per_setting[st.label].append(next(results))
        name = runs[0].name
        path = out / "entries" / f"{_file_name(name)}.json"
        given = {key: about[key].get(name) or kept[name][key] for key in about}  # or as resumed
        entry = make_entry(
            name,
            runs,
            per_setting,
            episodes,
            given["code"],
            given["notes"],
            split,
            given["class"] or None,
            given["chosen_on"],
        )
        atomic_write_text(path, entry_json(entry))
        paths.append(path)
    return paths


def _check_request(
    groups: list[list[Method]],
    names: list[str],
    about: dict[str, dict[str, str]],
    kept: dict[str, dict[str, str]],
    split: str,
    episodes: int,
) -> None:
    """ValueError, before anything is played, for a suite request that cannot give entries: methods
    without unique names, a training run listed twice (one run), ``about`` (code, notes, class,
    chosen-on) for a method not played, an episode count past the split's, a name, code link, notes or
    chosen-on the leaderboard would refuse, a method without a class or, on the test split, without what
    it was chosen on (given now or in its entry in ``out``, ``kept``)."""
    if not groups or len(set(names)) != len(names):
        raise ValueError(f"the suite needs methods with unique names (use NAME=METHOD), got {names}")
    for runs in groups:
        specs = [method_spec(m) for m in runs]
        if len(set(specs)) != len(specs):
            twice = next(s for s in specs if specs.count(s) > 1)
            raise ValueError(f"method {runs[0].name} lists the training run {twice} twice: each run once")
    unknown = sorted(set().union(*about.values()) - set(names))
    if unknown:
        raise ValueError(
            f"code / notes / class / chosen-on given for {unknown}, which the suite does not play "
            f"(methods: {names})"
        )
    if not 1 <= episodes <= EPISODES:
        raise ValueError(f"episodes must be from 1 to the {EPISODES} frozen maps of a split, got {episodes}")
    for runs, name in zip(groups, names):
        _check_stated(name, about, kept[name])
        method_class(name, runs, about["class"].get(name) or kept[name]["class"] or None)
        if split == "test" and not (about["chosen_on"].get(name) or kept[name]["chosen_on"]):
            raise ValueError(
                f"an entry on the test split states what {name} was chosen on: --chosen-on "
                f"{name}=TEXT (e.g. 'validation split', or 'nothing: a published planner')"
            )


def _check_stated(name: str, about: dict[str, dict[str, str]], kept: dict[str, str]) -> None:
    """ValueError naming the flag for a method name, code link, notes or chosen-on text the leaderboard
    would refuse in the entry (:func:`~catmip_rl.benchmark.entry_check.check_stated`, its own rule)."""
    for key in STATED:
        value = name if key == "method" else about[key].get(name) or kept[key]
        try:
            check_stated(key, value, empty=key != "method")
        except ValueError as err:
            flag = "--method NAME" if key == "method" else f"--{key.replace('_', '-')} {name}=..."
            raise ValueError(f"{flag}: {err}: the leaderboard would refuse the entry") from None


def _recorded(path: Path) -> dict[str, str]:
    """The ``code``, ``notes``, ``class`` and ``chosen_on`` of the entry already at ``path`` (empty
    when there is none): a resumed suite keeps what it was told before."""
    keys = ("code", "notes", "class", "chosen_on")
    try:
        entry = json.loads(path.read_text())
    except (OSError, ValueError):
        return dict.fromkeys(keys, "")
    return {k: entry.get(k, "") if isinstance(entry.get(k), str) else "" for k in keys}


def _file_name(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name).strip("_") or "method"
