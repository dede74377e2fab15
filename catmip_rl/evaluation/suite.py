"""The benchmark suite: one fixed grid of settings on frozen maps, one entry per method.

    run_suite(["nearest", "mine=py:my_policy.py:make_policy"], split="validation")  # catmip bench suite

**Suite v2** (:data:`SETTINGS`): Tasks 2 and 3 × communication full / σ = 4 / σ = 2 × SLAM noise 0 / 5 %,
each on 1,000 frozen maps of a **split** (:data:`~catmip_env.map_sets.SPLITS`, frozen in
``catmip_env/frozen_maps``): *validation* (seed 1000) for tuning, gates and every choice; *test* (seed
20261201), played once per entry after every choice is frozen -- the leaderboard ranks test entries
only. Evaluation activation, the paper's horizon, the longest macro-action 10 ticks. Task 1 is left out: every planner and
AMAT rescue within 0.02 of each other there by tick 100, so it no longer tells methods apart. Weak
communication and SLAM noise are where the planners differ most (RRT 0.64 against Nearest 0.48 on Task 2
at σ = 2) and where a learned planner can win.

Every (setting, method, training run) is one evaluation (:mod:`~catmip_rl.evaluation.jobs`) in
``OUT/runs/LABEL/NAME[/runK]/``; an interrupted suite resumes: a run whose results are complete is read
back, not played again. Each method then gets an **entry**, ``OUT/entries/NAME.json``
(:func:`make_entry`): per setting its rescue ticks (every map, every run), success by tick 100 and by
the horizon and the mean rescue tick with 95 % CIs, the maps' digest; an aggregate IQM over the
settings; where its files came from, the package versions, the CPU, its training compute (read from a
model file, or given). ``catmip leaderboard`` (:mod:`~catmip_rl.evaluation.leaderboard`) checks entries
and ranks them.
"""

from __future__ import annotations

import datetime
import hashlib
import json
import re
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import numpy as np

from catmip_env.machine import machine_info
from catmip_env.map_sets import MANIFEST_EPISODES, SPLITS
from catmip_rl.evaluation.evaluate import EvalSetting
from catmip_rl.evaluation.jobs import Job, check_methods, default_threads, map_jobs, run_dir
from catmip_rl.evaluation.methods import PLAY_OPTIONS, Method, method_source, parse_runs
from catmip_rl.evaluation.stats import CONFIDENCE, success_interval
from catmip_rl.evaluation.user_policy import PolicyError, parse_policy_source
from catmip_rl.files import atomic_write_text

__all__ = [
    "SUITE", "SPLITS", "EPISODES", "SETTINGS", "ENTRY_FORMAT", "run_suite", "make_entry", "setting_numbers",
    "iqm_interval", "maps_digest", "entry_json", "rescued_by_100",
]  # fmt: skip

SUITE = "v2"
EPISODES = MANIFEST_EPISODES
SETTINGS = tuple(
    EvalSetting(task, comm, noise)
    for task in ("task2", "task3")
    for comm in ("full", "4", "2")
    for noise in (0.0, 0.05)
)
ENTRY_FORMAT = "catmip-suite-entry-v2"
BY_TICK = 100  # the paper's headline: rescued by tick 100
RESAMPLES = 2_000
PACKAGES = ("catmip", "numpy", "numba", "torch", "torchrl", "tensordict")


def maps_digest(hashes: list[str]) -> str:
    """SHA-256 of a list of map hashes (:func:`~catmip_env.map_sets.map_hash`, one per map in order):
    an entry's digest is computed from the maps its runs played; the leaderboard computes the frozen
    split's from the manifest (:func:`split_digest`)."""
    return hashlib.sha256("\n".join(hashes).encode()).hexdigest()


def split_digest(task: str, split: str, episodes: int) -> str:
    """:func:`maps_digest` of the first ``episodes`` frozen maps of ``split`` for ``task``."""
    from catmip_env.map_sets import manifest

    return maps_digest(manifest(task)["seeds"][str(SPLITS[split])][:episodes])


def check_split(split: str) -> int:
    """The seed of ``split``; ValueError naming the splits for anything else."""
    if split not in SPLITS:
        raise ValueError(f"split must be one of {sorted(SPLITS)}, got {split!r}")
    return SPLITS[split]


def rescued_by_100(rescue_tick: np.ndarray, horizon: int) -> np.ndarray:
    """Per run and map (bool): rescued by tick 100 (or by the horizon if shorter); -1 is never."""
    ticks = np.asarray(rescue_tick, np.int64)
    return (ticks >= 0) & (ticks <= min(BY_TICK, horizon))


def setting_numbers(
    rescue_tick: np.ndarray, horizon: int, seed: int = 0, intervals: bool = True
) -> dict[str, Any]:
    """What an entry states for one setting, from its rescue ticks ((runs, maps), -1: not rescued):
    success by tick 100 and by the horizon (means over runs and maps, 95 % CIs over the maps, or runs and
    maps together for several runs; ``intervals=False``: the means only) and the mean rescue tick of the
    rescued episodes."""
    ticks = np.asarray(rescue_tick, np.int64)
    rescued = ticks >= 0
    by_100 = rescued_by_100(ticks, horizon)
    out: dict[str, Any] = {}
    for key, success in (("success_by_100", by_100), ("success_rate", rescued)):
        out[key] = float(success.mean())
        if intervals:
            low, high, _over = success_interval(success, seed)
            out[f"{key}_ci"] = [low, high]
    out["mean_rescue_tick"] = float(ticks[rescued].mean()) if rescued.any() else None
    return out


def iqm_interval(success: list[np.ndarray], seed: int = 0) -> tuple[float, float, float]:
    """IQM of success by tick 100 over (runs × settings) with its 95 % CI (``success``: one (runs, maps)
    bool array per setting). Each resample draws the runs, and each setting's maps, with replacement:
    rliable's stratified bootstrap resamples runs only, which with one or three runs hides the maps'
    share of the uncertainty (the same reason as ``compare.runs_and_maps_ci``)."""
    from scipy.stats import trim_mean

    rng = np.random.default_rng(seed)
    scores = np.stack([s.mean(axis=1) for s in success], axis=1)  # (runs, settings)
    point = float(trim_mean(scores.ravel(), 0.25))
    runs = scores.shape[0]
    pick = rng.integers(runs, size=(RESAMPLES, runs))  # the runs of each resample, alike in every setting
    means = np.empty((RESAMPLES, runs, len(success)))
    for k, s in enumerate(success):  # each setting's maps drawn with replacement: (resamples, runs) means
        maps = rng.integers(s.shape[1], size=(RESAMPLES, s.shape[1]))
        per_map = s[:, maps].mean(axis=2).T  # (resamples, runs): every run's mean on the drawn maps
        means[:, :, k] = np.take_along_axis(per_map, pick, axis=1)
    draws = trim_mean(means.reshape(RESAMPLES, -1), 0.25, axis=1)
    low, high = np.quantile(draws, [(1 - CONFIDENCE) / 2, (1 + CONFIDENCE) / 2])
    return point, float(low), float(high)


def _versions() -> dict[str, str | None]:
    found = {}
    for name in PACKAGES:
        try:
            found[name] = version(name)
        except PackageNotFoundError:
            found[name] = None
    return found


def _training(method: Method) -> dict[str, Any] | None:
    """A model file's training record (minutes, iterations, episodes, seed), None for other methods."""
    if method.kind != "amat":
        return None
    from catmip_rl.checkpoint import model_record

    return model_record(method.target)


def _files(results: dict[str, list[dict[str, Any]]], k: int) -> list[dict[str, str]] | None:
    """The files training run ``k`` played from over the settings (its policy's ``files`` with their
    SHA-256, e.g. a ``py:`` policy's weights for each task), None if its policy names none."""
    found = {f["file"]: f for res in results.values() for f in res[k]["summary"].get("policy_files") or []}
    return [_shown_file(found[name]) for name in sorted(found)] or None


def _shown(path: str) -> str:
    """``path`` relative to the working directory where it lies below it (``run-records/x/policy.pt``,
    as a clone of the entry's repository names it), else as given: an entry names no home folders."""
    try:
        return str(Path(path).relative_to(Path.cwd()))
    except ValueError:
        return path


def _shown_file(record: dict[str, str] | None) -> dict[str, str] | None:
    return record and {**record, "file": _shown(record["file"])}


def _shown_target(method: Method) -> str:
    if method.kind == "amat":  # a model file (a shipped model's name resolves to one)
        return _shown(method.target)
    if method.kind != "py" or not (src := parse_policy_source(method.target)).is_file:
        return method.target
    return f"py:{_shown(src.source)}:{src.factory}"


def entry_actions(summary: dict[str, Any]) -> str | None:
    """How an entry's policy chose its actions, from a run's summary: its ``actions`` ("argmax",
    "sampled", "its own"), with " + loop guard" and " + clean occupancy" where an AMAT played with them."""
    actions = summary.get("actions")
    if not actions:
        return actions
    options = [name for key, name in PLAY_OPTIONS if summary.get(key)]
    return " + ".join([actions, *options])


def make_entry(name: str, runs: list[Method], results: dict[str, list[dict[str, Any]]], episodes: int,
               code: str = "", notes: str = "", split: str = "validation") -> dict[str, Any]:  # fmt: skip
    """The suite entry of method ``name`` (its training ``runs``) on ``split`` from its
    :func:`~catmip_rl.evaluation.jobs.run_one` results per setting label (one per run, in order); each
    setting's ``maps_sha256`` is the digest of the maps its runs played (ValueError if they differ)."""
    settings, success = {}, []
    for st in SETTINGS:
        res = results[st.label]
        horizon = int(res[0]["summary"]["horizon"])
        played = {maps_digest(r["maps"]) for r in res}
        if len(played) != 1:
            raise ValueError(f"the runs of {name} played different maps in {st.label}")
        ticks = np.array([[-1 if np.isnan(t) else int(t) for t in r["ticks"]["rescue_tick"]] for r in res])
        settings[st.label] = {
            "task": st.task, "comm": st.comm, "noise": st.noise, "max_ma_ticks": st.max_ma_ticks,
            "horizon": horizon, "maps_sha256": played.pop(),
            **setting_numbers(ticks, horizon), "rescue_tick": ticks.tolist(),
        }  # fmt: skip
        success.append(rescued_by_100(ticks, horizon))
    iqm, low, high = iqm_interval(success)
    first = results[SETTINGS[0].label][0]["summary"]
    return {
        "format": ENTRY_FORMAT,
        "suite": SUITE,
        "method": name,
        "actions": entry_actions(first),
        "runs": [
            {
                "kind": m.kind,
                "target": _shown_target(m),
                "source": _shown_file(method_source(m)),
                "files": _files(results, k),
                "training": _training(m),
            }
            for k, m in enumerate(runs)
        ],  # fmt: skip
        "split": split,
        "seed": check_split(split),
        "episodes": episodes,
        "aggregate": {"iqm_success_by_100": iqm, "iqm_success_by_100_ci": [low, high]},
        "settings": settings,
        "code": code,
        "notes": notes,
        "versions": _versions(),
        "machine": machine_info(),
        "created": datetime.date.today().isoformat(),
    }


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
) -> list[Path]:
    """Play every method (``NAME=SPEC`` or ``NAME=SPEC,SPEC,...`` for several training runs) on every
    setting of the suite on the maps of ``split`` and write one entry per method, with its ``code`` link and ``notes`` (by
    method name) where given, else those of the entry already in ``out``; returns the entries' paths.
    Resumes an interrupted suite in the same ``out``. A method that cannot play a setting
    (``WorldNotSupported``), an unreadable model or a broken policy raises before anything is played."""
    seed = check_split(split)
    groups = [parse_runs(m) for m in methods]
    names = [runs[0].name for runs in groups]
    if not groups or len(set(names)) != len(names):
        raise ValueError(f"the suite needs methods with unique names (use NAME=METHOD), got {names}")
    unknown = sorted((set(code or {}) | set(notes or {})) - set(names))
    if unknown:
        raise ValueError(
            f"code / notes given for {unknown}, which the suite does not play (methods: {names})"
        )
    if not 1 <= episodes <= EPISODES:
        raise ValueError(f"episodes must be from 1 to the {EPISODES} frozen maps of a split, got {episodes}")
    panels = [(st.label, st) for st in SETTINGS]
    _plays, not_played = check_methods(groups, panels, seed)
    if not_played:
        (label, name), why = next(iter(not_played.items()))
        raise ValueError(f"method {name} cannot play {label} ({why}): a suite entry needs every setting")
    threads = default_threads(jobs, threads)
    out = Path(out)
    tasks = [
        Job(m, st, episodes, seed, str(run_dir(out / "runs" / st.label / m.name, k, len(runs))), threads,
            resume=True, sampled=False)  # an entry is the argmax (or the policy's own) actions: one pass
        for runs in groups for k, m in enumerate(runs) for st in SETTINGS
    ]  # fmt: skip
    try:
        results = iter(map_jobs(tasks, jobs, progress, f"suite {SUITE}"))
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
        kept = _recorded(path)  # a resumed suite keeps the link and notes it was given before
        entry = make_entry(name, runs, per_setting, episodes, (code or {}).get(name, kept["code"]),
                           (notes or {}).get(name, kept["notes"]), split)  # fmt: skip
        atomic_write_text(path, entry_json(entry))
        paths.append(path)
    return paths


def entry_json(entry: dict[str, Any]) -> str:
    """An entry as JSON, indented, with each list of numbers on one line (12 x 1,000 ticks a run)."""
    text = json.dumps(entry, indent=1)
    return re.sub(
        r"\[\s*(-?[\d.e+-]+(?:,\s*-?[\d.e+-]+)*)\s*\]",
        lambda m: "[" + re.sub(r"\s+", "", m.group(1)) + "]",
        text,
    )


def _recorded(path: Path) -> dict[str, str]:
    """The ``code`` and ``notes`` of the entry already at ``path`` (empty when there is none)."""
    try:
        entry = json.loads(path.read_text())
    except (OSError, ValueError):
        return {"code": "", "notes": ""}
    return {k: entry.get(k, "") if isinstance(entry.get(k), str) else "" for k in ("code", "notes")}


def _file_name(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name).strip("_") or "method"
