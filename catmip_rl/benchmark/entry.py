"""What a suite entry is: the suite's grid (:data:`SETTINGS`, the splits), an entry's numbers and how
one is made from its runs (:func:`make_entry`), its method's class (:func:`method_class`) and the spec
that plays each training run again (:func:`method_spec`). Checking an entry is
:mod:`~catmip_rl.benchmark.entry_check`'s; playing the suite, :mod:`~catmip_rl.benchmark.suite`'s.

An entry (``catmip-suite-entry-v2``): the method, its class (planner / learned / hybrid / floor) and what
it was chosen on, its training runs (spec, files with their SHA-256, training compute), the split and
its seed, per setting its rescue ticks (every map, every run), success by tick 100 and by the horizon
with 95 % CIs, the mean rescue tick and the digest of the maps its runs played; an aggregate IQM over
the settings; the package versions, the CPU and the date.
"""

from __future__ import annotations

import datetime
import hashlib
import json
import math
import re
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from statistics import NormalDist
from typing import Any

import numpy as np

from catmip_env.maps.map_sets import MANIFEST_EPISODES, SPLITS
from catmip_env.runtime.machine import machine_info
from catmip_rl.evaluation.evaluate import EvalSetting
from catmip_rl.evaluation.methods import PLAY_OPTIONS, Method, method_source
from catmip_rl.evaluation.stats import CONFIDENCE, runs_and_maps_ci
from catmip_rl.evaluation.user_policy import parse_policy_source

__all__ = [
    "SUITE",
    "SPLITS",
    "EPISODES",
    "SETTINGS",
    "ENTRY_FORMAT",
    "CLASSES",
    "FLOORS",
    "BY_TICK",
    "make_entry",
    "setting_numbers",
    "iqm_interval",
    "maps_digest",
    "split_digest",
    "check_split",
    "entry_json",
    "rescued_by_100",
    "entry_actions",
    "method_class",
    "method_spec",
    "package_versions",
]

SUITE = "v2"
EPISODES = MANIFEST_EPISODES
SETTINGS = tuple(
    EvalSetting(task, comm, noise)
    for task in ("task2", "task3")
    for comm in ("full", "4", "2")
    for noise in (0.0, 0.05)
)
ENTRY_FORMAT = "catmip-suite-entry-v2"
CLASSES = ("planner", "learned", "hybrid", "floor", "reference")
"""An entry's class: a planner; a learned policy (plays from its own observations); a hybrid (reads a
planner at play time, e.g. an AMAT with ``AmatConfig.hint``); a floor (no skill: the random planners); a
reference (project code that reads the true world, :mod:`catmip_env.planners.reference`: the headroom,
shown under the ranked table and never ranked). Only the project's reference rows are references."""
RANKED = ("planner", "learned", "hybrid", "floor")
FLOORS = ("random-frontier", "random-rescue", "random-uniform")
BY_TICK = 100  # the paper's headline: rescued by tick 100
RESAMPLES = 2_000
PACKAGES = ("catmip", "numpy", "numba", "torch", "torchrl", "tensordict")


def maps_digest(hashes: list[str]) -> str:
    """SHA-256 of a list of map hashes (:func:`~catmip_env.maps.map_sets.map_hash`, one per map in order):
    an entry's digest is computed from the maps its runs played; the leaderboard computes the frozen
    split's from the manifest (:func:`split_digest`)."""
    return hashlib.sha256("\n".join(hashes).encode()).hexdigest()


def split_digest(task: str, split: str, episodes: int) -> str:
    """:func:`maps_digest` of the first ``episodes`` frozen maps of ``split`` for ``task``."""
    from catmip_env.maps.map_sets import manifest

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
            out[f"{key}_ci"] = list(_interval(success, seed))
    out["mean_rescue_tick"] = float(ticks[rescued].mean()) if rescued.any() else None
    return out


def _interval(success: np.ndarray, seed: int) -> tuple[float, float]:
    """95 % CI of a success rate ((runs, maps) bool): Wilson's score interval over the maps for one run
    (exact, so the leaderboard re-checks it at no cost), the bootstrap over runs and maps together for
    several (:func:`~catmip_rl.evaluation.stats.runs_and_maps_ci`)."""
    if success.shape[0] > 1:
        return runs_and_maps_ci(success, seed)
    n, k = success.shape[1], int(success.sum())
    z = NormalDist().inv_cdf((1 + CONFIDENCE) / 2)
    centre = (k + z * z / 2) / (n + z * z)
    half = z * math.sqrt(k * (n - k) / n + z * z / 4) / (n + z * z)
    return max(0.0, centre - half), min(1.0, centre + half)


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


def package_versions() -> dict[str, str | None]:
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
    from catmip_rl.store.checkpoint import model_record

    return model_record(method.target)


def _files(results: dict[str, list[dict[str, Any]]], k: int) -> list[dict[str, str]] | None:
    """The files training run ``k`` played from over the settings (its policy's ``files`` with their
    SHA-256, e.g. a ``py:`` policy's weights for each task, and the modules it imported from its own
    folder), None if there are none."""
    found = {
        f["file"]: f
        for res in results.values()
        for key in ("policy_files", "policy_modules")
        for f in res[k]["summary"].get(key) or []
    }
    return [_shown_file(found[name]) for name in sorted(found)] or None


def _base() -> Path:
    """The folder an entry's paths start in: the root of the git repository the working directory is in
    (a clone replays the entry from its root), else the working directory."""
    here = Path.cwd().resolve()
    return next((d for d in (here, *here.parents) if (d / ".git").exists()), here)


def _shown(path: str) -> str:
    """``path`` relative to the repository (:func:`_base`) where it lies inside it
    (``run-records/x/policy.pt``, as a clone of the entry's repository names it), else as given: a file
    outside names an absolute path that only this machine can replay."""
    try:
        return str(Path(path).resolve().relative_to(_base()))
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


def method_spec(method: Method) -> str:
    """The spec that plays ``method`` again (:func:`~catmip_rl.evaluation.methods.parse_method`, without
    its name): what a leaderboard replay rebuilds each training run from."""
    if method.kind == "amat":
        prefix = "amat-guard:" if method.loop_guard else "amat-clean:" if method.clean_occupancy else "amat:"
        return prefix + _shown_target(method)  # a synchronous model plays synchronously by itself
    spec = {"window": "window:", "window-noheading": "window-noheading:"}.get(method.kind, "")
    spec += _shown_target(method)
    return f"sync:{spec}" if method.synchronous else spec


def _derived_class(method: Method) -> str | None:
    """The class a method's kind gives (None for a ``py:`` policy, which states its own)."""
    if method.kind in ("planner", "window", "window-noheading"):
        return "floor" if method.target in FLOORS else "planner"
    if method.kind == "reference":
        return "reference"
    if method.kind == "amat":
        from catmip_rl.store.checkpoint import load_model

        return "hybrid" if load_model(method.target).config.hint else "learned"
    return None


def method_class(name: str, runs: list[Method], stated: str | None = None) -> str:
    """The class of method ``name`` (:data:`CLASSES`): from its runs' kind (a planner, a floor, an AMAT
    that reads a planner or not); a ``py:`` policy's as ``stated`` (``--class NAME=CLASS``). ValueError
    for a ``py:`` policy that states none, a stated class its runs contradict, or runs of two classes."""
    if stated is not None and stated not in CLASSES:
        raise ValueError(f"--class {name}={stated}: the class must be one of {', '.join(CLASSES)}")
    found = {_derived_class(m) for m in runs}
    if found == {None}:
        if stated == "reference":
            raise ValueError(
                f"--class {name}=reference: only the project's reference rows are references; state one of "
                f"{', '.join(RANKED)}"
            )
        if stated is None:
            raise ValueError(
                f"method {name} is your policy: state its class with --class {name}=CLASS, one of "
                f"{', '.join(CLASSES)} (learned: it plays from its own observations; hybrid: it reads a "
                "planner at play time)"
            )
        return stated
    if len(found) != 1:
        raise ValueError(f"the training runs of {name} are of different classes: {sorted(map(str, found))}")
    derived = found.pop()
    if stated is not None and stated != derived:
        raise ValueError(f"--class {name}={stated}, but {name} is a {derived} (from what it plays)")
    return derived


def make_entry(
    name: str,
    runs: list[Method],
    results: dict[str, list[dict[str, Any]]],
    episodes: int,
    code: str = "",
    notes: str = "",
    split: str = "validation",
    cls: str | None = None,
    chosen_on: str = "",
) -> dict[str, Any]:
    """The suite entry of method ``name`` (its training ``runs``, of class ``cls`` or the one they
    give, :func:`method_class`; ``chosen_on``: what its choices were made on) on ``split`` from its
    :func:`~catmip_rl.benchmark.jobs.run_one` results per setting label (one per run, in order); each
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
            "task": st.task,
            "comm": st.comm,
            "noise": st.noise,
            "max_ma_ticks": st.max_ma_ticks,
            "horizon": horizon,
            "maps_sha256": played.pop(),
            **setting_numbers(ticks, horizon),
            "rescue_tick": ticks.tolist(),
        }
        success.append(rescued_by_100(ticks, horizon))
    iqm, low, high = iqm_interval(success)
    first = results[SETTINGS[0].label][0]["summary"]
    played_on = _played_on(results)
    return {
        "format": ENTRY_FORMAT,
        "suite": SUITE,
        "method": name,
        "class": method_class(name, runs, cls),
        "chosen_on": chosen_on,
        "actions": entry_actions(first),
        "runs": [
            {
                "spec": method_spec(m),
                "kind": m.kind,
                "target": _shown_target(m),
                "source": _shown_file(method_source(m)),
                "files": _files(results, k),
                "training": _training(m),
            }
            for k, m in enumerate(runs)
        ],
        "split": split,
        "seed": check_split(split),
        "episodes": episodes,
        "aggregate": {"iqm_success_by_100": iqm, "iqm_success_by_100_ci": [low, high]},
        "settings": settings,
        "code": code,
        "notes": notes,
        "versions": package_versions(),
        "machine": machine_of(played_on),
        "played_on": played_on,
        "created": datetime.date.today().isoformat(),
    }


def machine_of(played_on: list[dict[str, Any]], what: str = "the entry's maps were played") -> dict[str, Any]:
    """The machine ticks were computed on (what a replay compares its own with): the first that played,
    without its host name; this one if none is recorded. ValueError for machines of different CPU
    capability, whose ticks a replay could not tell apart (``what`` names them in the message)."""
    kinds = {(m.get("cpu_capability"), m.get("native_bf16")) for m in played_on}
    if len(kinds) > 1:
        raise ValueError(
            f"{what} on CPUs of different capability ({sorted(map(str, kinds))}): play it on machines of "
            "one kind (a Ray cluster of one CPU type, or --backend local)"
        )
    return {k: v for k, v in played_on[0].items() if k != "host"} if played_on else machine_info()


def _played_on(results: dict[str, list[dict[str, Any]]]) -> list[dict[str, Any]]:
    """Every machine that played a chunk of the entry's runs (:func:`~catmip_rl.benchmark.jobs.map_jobs`),
    once each, in the order first met: with ``machine`` and ``created``, what differs between an entry
    played on a Ray cluster and one played here."""
    seen: list[dict[str, Any]] = []
    for st in SETTINGS:
        for r in results[st.label]:
            seen += [m for m in r.get("machines") or [] if m not in seen]
    return seen


def entry_json(entry: dict[str, Any]) -> str:
    """An entry as JSON, indented, with each list of numbers on one line (12 x 1,000 ticks a run)."""
    text = json.dumps(entry, indent=1)
    return re.sub(
        r"\[\s*(-?[\d.e+-]+(?:,\s*-?[\d.e+-]+)*)\s*\]",
        lambda m: "[" + re.sub(r"\s+", "", m.group(1)) + "]",
        text,
    )
