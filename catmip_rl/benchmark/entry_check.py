"""Checking suite entries: what ``catmip leaderboard`` accepts, before it ranks anything.

An entry (:mod:`~catmip_rl.benchmark.entry`) is accepted only if it is one of this suite: its format
and version; a split and that split's seed and every map of it; every setting and no other, each with
the suite's horizon; its maps' digest equal to the frozen maps' (``catmip_env/maps/frozen_maps``); one list
of rescue ticks per training run and map, each -1 or a tick within the horizon; a class, what it was
chosen on, and every number it states -- rates, means, intervals, the aggregate -- equal to the number
recomputed from those ticks. Strings are bounded and hold no control characters, a code link is a web
address or a relative path, sizes are bounded (the file, its runs, its files), and only regular files
are read. A refused entry is one line naming its file and the first problem (:class:`EntryError`).
"""

from __future__ import annotations

import json
import math
import re
import stat
from pathlib import Path
from typing import Any

import numpy as np

from catmip_env.maps.map_sets import SPLITS
from catmip_env.planners.reference import REFERENCES
from catmip_rl.benchmark.entry import (
    CLASSES,
    ENTRY_FORMAT,
    EPISODES,
    SETTINGS,
    SUITE,
    iqm_interval,
    rescued_by_100,
    setting_numbers,
    split_digest,
)
from catmip_rl.evaluation.evaluate import EvalSetting

__all__ = [
    "EntryError",
    "check_entry",
    "check_stated",
    "load_entries",
    "read_entry",
    "STATED",
    "MAX_ENTRY_BYTES",
    "MAX_RUNS",
]

MAX_ENTRY_BYTES = 4 * 2**20  # 10 runs x 12 settings x 1,000 ticks is under 1 MB
MAX_ENTRIES = 500
MAX_RUNS = 10
MAX_FILES = 50  # files a run names
TEXT_LIMITS = {"method": 64, "chosen_on": 300, "code": 300, "notes": 1_000, "actions": 80, "spec": 500}
STATED = ("method", "code", "notes", "chosen_on")
"""What an entry states of its method as the suite was told it (:func:`check_stated`)."""
KEYS = {
    "format",
    "suite",
    "method",
    "class",
    "chosen_on",
    "actions",
    "runs",
    "split",
    "seed",
    "episodes",
    "aggregate",
    "settings",
    "code",
    "notes",
    "versions",
    "machine",
    "played_on",
    "created",
}
_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f\u2028\u2029\u200e\u200f\u202a-\u202e\u2066-\u2069]")  # + bidi
_SHA256 = re.compile(r"[0-9a-f]{64}")
_PATH = re.compile(r"[A-Za-z0-9._~/+-]+")


class EntryError(ValueError):
    """An entry the leaderboard refuses (the message names the file and the problem)."""


def _text(value: Any, what: str, limit: int, empty: bool = True) -> str:
    if not isinstance(value, str):
        raise ValueError(f"{what} must be a string, got {type(value).__name__}")
    if len(value) > limit:
        raise ValueError(f"{what} is {len(value):,} characters, at most {limit:,}")
    if _CONTROL.search(value):
        raise ValueError(f"{what} holds a control character (a newline, a tab, ...)")
    if not empty and not value.strip():
        raise ValueError(f"{what} is empty")
    return value


def check_stated(key: str, value: Any, empty: bool = True) -> str:
    """``value`` as an entry may state its ``key`` (:data:`STATED`: what a suite is told of a method): a
    string of at most ``TEXT_LIMITS[key]`` characters without control characters, not blank unless
    ``empty``; a ``code`` link is empty, an http(s) address or a relative path (no other scheme).
    ValueError naming the key: the leaderboard refuses such an entry, the suite such a request."""
    text = _text(value, key, TEXT_LIMITS[key], empty)
    if key != "code" or not text or re.fullmatch(r"https?://[^\s<>\"'|\\`]+", text):
        return text
    if ":" in text or text.startswith("/") or not _PATH.fullmatch(text):
        raise ValueError(f"code {text!r} is neither an http(s) address nor a relative path")
    return text


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _same(stated: Any, recomputed: float | None) -> bool:
    if recomputed is None or stated is None:
        return stated is None and recomputed is None
    return _number(stated) and math.isclose(stated, recomputed, rel_tol=0, abs_tol=1e-9)


def _same_interval(stated: Any, recomputed: list[float]) -> bool:
    return isinstance(stated, list) and len(stated) == 2 and all(map(_same, stated, recomputed))


def _ticks(entry: dict[str, Any], label: str, horizon: int, episodes: int) -> np.ndarray:
    ticks = entry["settings"][label].get("rescue_tick")
    runs = len(entry["runs"])
    if not isinstance(ticks, list) or len(ticks) != runs:
        raise ValueError(f"{label}: rescue_tick must hold one list per training run ({runs})")
    for run in ticks:
        if not isinstance(run, list) or len(run) != episodes or not all(type(t) is int for t in run):
            raise ValueError(f"{label}: each run's rescue_tick must be {episodes} integers (one per map)")
        bad = next((t for t in run if not -1 <= t <= horizon), None)
        if bad is not None:
            raise ValueError(f"{label}: rescue tick {bad} is neither -1 (not rescued) nor in 0 .. {horizon}")
    return np.array(ticks, np.int64)


def _setting_ticks(entry: dict[str, Any], st: EvalSetting, episodes: int) -> tuple[np.ndarray, int]:
    """The rescue ticks ``(runs, episodes)`` and horizon of setting ``st`` of ``entry``; ValueError
    unless the setting is the suite's (task, communication, noise, macro-action length, horizon, the
    split's frozen maps)."""
    stated = entry["settings"][st.label]
    if not isinstance(stated, dict):
        raise ValueError(f"{st.label}: not an object")
    for key in ("task", "comm", "noise", "max_ma_ticks"):
        if stated.get(key) != getattr(st, key) or type(stated.get(key)) is bool:
            suite_value = getattr(st, key)
            raise ValueError(f"{st.label}: {key} is {stated.get(key)!r}, the suite's is {suite_value!r}")
    horizon = st.env_config().horizon_ticks
    if type(stated.get("horizon")) is not int or stated["horizon"] != horizon:
        raise ValueError(f"{st.label}: horizon {stated.get('horizon')!r}, the suite's is {horizon}")
    if stated.get("maps_sha256") != split_digest(st.task, entry["split"], episodes):
        raise ValueError(
            f"{st.label}: its maps are not the frozen {entry['split']} maps (maps_sha256 differs)"
        )
    return _ticks(entry, st.label, horizon, episodes), horizon


def _check_runs(runs: Any) -> None:
    if not isinstance(runs, list) or not runs:
        raise ValueError("it lists no training run")
    if len(runs) > MAX_RUNS:
        raise ValueError(f"it lists {len(runs)} training runs, at most {MAX_RUNS}")
    for k, run in enumerate(runs):
        if not isinstance(run, dict):
            raise ValueError(f"run {k} is not an object")
        _text(run.get("spec"), f"run {k}'s spec", TEXT_LIMITS["spec"], empty=False)
        files = [run.get("source")] + (run.get("files") or [])
        if not isinstance(run.get("files") or [], list) or len(files) > MAX_FILES:
            raise ValueError(f"run {k}'s files must be a list of at most {MAX_FILES - 1}")
        for f in files:
            if f is None:
                continue
            if not isinstance(f, dict) or not _SHA256.fullmatch(str(f.get("sha256"))):
                raise ValueError(f"run {k} names a file without its SHA-256 ({{'file', 'sha256'}})")
            _text(f.get("file"), f"run {k}'s file", TEXT_LIMITS["spec"], empty=False)


def _reference_spec(spec: Any, method: Any) -> bool:
    """Whether a run's ``spec`` plays a reference row: exactly one of :data:`REFERENCES`' names, under
    its own name. ValueError for a spec that plays one in any other spelling (spaces, ``sync:``) or under
    another method name: a reference row is never disguised as another row."""
    plain = str(spec).strip()
    while plain.startswith("sync:"):
        plain = plain[len("sync:") :].strip()
    if plain not in REFERENCES:
        return False
    if spec != plain or method != plain:
        raise ValueError(
            f"run spec {spec!r} plays the reference row {plain!r}: a reference row's entry is method {plain} "
            f"with spec {plain}, class reference"
        )
    return True


def _check_header(entry: Any, episodes: int) -> None:
    """ValueError unless ``entry`` is an entry of this suite (format, suite, split and its seed,
    episodes, known keys only), names a method, a class and what it was chosen on, its training runs,
    and holds every setting of the suite and no other."""
    if not isinstance(entry, dict) or entry.get("format") != ENTRY_FORMAT:
        raise ValueError(f"not a {ENTRY_FORMAT} file")
    extra = sorted(set(entry) - KEYS)
    if extra:
        raise ValueError(f"unknown field(s) {extra[:5]}")
    split = entry.get("split")
    if split not in SPLITS:
        raise ValueError(f"split is {split!r}, not one of {sorted(SPLITS)}")
    for key, want in (("suite", SUITE), ("seed", SPLITS[split]), ("episodes", episodes)):
        if entry.get(key) != want or type(entry.get(key)) is bool:
            raise ValueError(f"{key} is {entry.get(key)!r}, the leaderboard's is {want!r}")
    check_stated("method", entry.get("method"), empty=False)
    if entry.get("class") not in CLASSES:
        raise ValueError(f"class is {entry.get('class')!r}, not one of {', '.join(CLASSES)}")
    check_stated("chosen_on", entry.get("chosen_on"), empty=split != "test")
    check_stated("notes", entry.get("notes", ""))
    _text(entry.get("actions") or "", "actions", TEXT_LIMITS["actions"])
    check_stated("code", entry.get("code", ""))
    _check_runs(entry.get("runs"))
    played = entry.get("played_on", [])
    plain = (str, bool, int, float)
    if (
        not isinstance(played, list)
        or len(played) > 1024
        or not all(isinstance(m, dict) and all(isinstance(v, plain) for v in m.values()) for m in played)
    ):
        raise ValueError("played_on must be a list of machines (objects of plain values), at most 1024")
    references = {_reference_spec(run.get("spec"), entry["method"]) for run in entry["runs"]}
    if references != {entry["class"] == "reference"}:
        raise ValueError(
            "class reference belongs to the project's reference rows (catmip_env.planners.reference) "
            f"alone, and they to it: class {entry['class']!r}, runs {[r.get('spec') for r in entry['runs']]}"
        )
    settings = entry.get("settings")
    labels = [st.label for st in SETTINGS]
    if not isinstance(settings, dict):
        raise ValueError("it has no settings")
    missing, extra = [s for s in labels if s not in settings], sorted(set(settings) - set(labels))
    if missing or extra:
        problem = f"missing setting(s) {missing}" if missing else f"setting(s) not in suite {SUITE}: {extra}"
        raise ValueError(problem)


def check_entry(entry: Any, episodes: int = EPISODES) -> dict[str, Any]:
    """The leaderboard's numbers of ``entry`` (aggregate and per setting, recomputed from its ticks, and
    ``success``: per setting whether each run rescued each map by tick 100, (runs, maps)); ValueError
    naming the first thing that makes it no entry of this suite or a number its ticks do not give."""
    _check_header(entry, episodes)
    numbers, success = {}, {}
    for st in SETTINGS:
        ticks, horizon = _setting_ticks(entry, st, episodes)
        numbers[st.label] = setting_numbers(ticks, horizon)
        stated = entry["settings"][st.label]
        for key, value in numbers[st.label].items():
            same = _same_interval if key.endswith("_ci") else _same
            if not same(stated.get(key), value):
                raise ValueError(
                    f"{st.label}: {key} {stated.get(key)!r} is not what its rescue ticks give ({value!r})"
                )
        success[st.label] = rescued_by_100(ticks, horizon)
    iqm, low, high = iqm_interval(list(success.values()))
    aggregate = entry.get("aggregate") if isinstance(entry.get("aggregate"), dict) else {}
    if not _same(aggregate.get("iqm_success_by_100"), iqm):
        raise ValueError(f"aggregate iqm_success_by_100 is not what its rescue ticks give ({iqm!r})")
    if not _same_interval(aggregate.get("iqm_success_by_100_ci"), [low, high]):
        raise ValueError(
            f"aggregate iqm_success_by_100_ci is not what its rescue ticks give ({[low, high]!r})"
        )
    return {"iqm": iqm, "iqm_ci": [low, high], "settings": numbers, "success": success}


def read_entry(path: Path) -> dict[str, Any]:
    """An entry file's JSON: a regular file of at most :data:`MAX_ENTRY_BYTES` (a FIFO or a device is
    never opened); ValueError otherwise."""
    try:
        info = path.stat()
    except OSError as err:
        raise ValueError(f"unreadable ({err.strerror})") from None
    if not stat.S_ISREG(info.st_mode):
        raise ValueError("not a regular file")
    if info.st_size > MAX_ENTRY_BYTES:
        raise ValueError(f"{info.st_size:,} bytes, an entry is at most {MAX_ENTRY_BYTES:,}")
    try:
        with open(path, "rb") as f:
            data = f.read(MAX_ENTRY_BYTES + 1)
        return json.loads(data, parse_constant=_no_constant)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as err:
        raise ValueError(f"unreadable ({' '.join(str(err).split())[:200]})") from None


def _no_constant(name: str) -> None:
    raise json.JSONDecodeError(f"{name} is not a number an entry may hold", name, 0)


def load_board(
    folder: str | Path, episodes: int = EPISODES, split: str = "test"
) -> tuple[list[dict[str, Any]], list[dict[str, Any]], list[tuple[str, str]]]:
    """The entries of ``folder`` as a board sees them: those of ``episodes`` maps a setting, the previews
    (fewer maps, each checked on its own count), and the refused ones, ``(file, one line)``: a file that
    is no entry of this suite, of another split, more maps than the board's, or a method an earlier
    file (by name) already names. :class:`EntryError` only for a folder that is missing, empty or too
    full."""
    entries, previews, refused, by_name = [], [], [], {}
    for path in _entry_paths(Path(folder)):
        try:
            entry = read_entry(path)
            own = entry.get("episodes") if isinstance(entry, dict) else None
            preview = type(own) is int and 1 <= own < episodes
            entry["checked"] = check_entry(entry, own if preview else episodes)
            if entry["split"] != split:
                raise ValueError(
                    f"it is on the {entry['split']} split; this leaderboard ranks the {split} split's "
                    f"entries only (--split {entry['split']} shows those)"
                )
            if entry["method"] in by_name:
                raise ValueError(f"{by_name[entry['method']]} already names the method {entry['method']!r}")
        except (ValueError, TypeError, KeyError, OverflowError) as err:
            refused.append((path.name, " ".join(str(err).split())))
            continue
        by_name[entry["method"]] = path.name
        (previews if preview else entries).append(entry | {"file": path.name, "path": str(path)})
    return entries, previews, refused


def _entry_paths(folder: Path) -> list[Path]:
    """The entry files of ``folder`` (``*.json``, hidden files left out: a writer's temporary files)."""
    if not folder.is_dir():
        raise EntryError(f"no such folder of entries: {folder}")
    paths = sorted(p for p in folder.glob("*.json") if not p.name.startswith("."))
    if not paths:
        raise EntryError(f"no entries (*.json) in {folder}")
    if len(paths) > MAX_ENTRIES:
        raise EntryError(f"{len(paths)} entries in {folder}, at most {MAX_ENTRIES}")
    return paths


def load_entries(folder: str | Path, episodes: int = EPISODES, split: str = "test") -> list[dict[str, Any]]:
    """Every ``*.json`` entry in ``folder``, checked (:func:`check_entry`), with the leaderboard's numbers
    under ``"checked"``; all on ``split`` (the leaderboard ranks the test split's). Hidden files (a name
    starting with ".": what a writer killed mid-write left, ``.NAME.PID-RANDOM.tmp.json``) are no
    entries. :class:`EntryError` naming the first bad file, an entry of another split, two entries of one
    method, or an empty or missing folder."""
    paths = _entry_paths(Path(folder))
    entries, by_name = [], {}
    for path in paths:
        try:
            entry = read_entry(path)
            entry["checked"] = check_entry(entry, episodes)
        except (ValueError, TypeError, KeyError, OverflowError) as err:
            raise EntryError(f"entry {path} refused: {err}") from None
        if entry["split"] != split:
            raise EntryError(
                f"entry {path} is on the {entry['split']} split; this leaderboard ranks the {split} split's "
                f"entries only (--split {entry['split']} ranks those)"
            )
        if entry["method"] in by_name:
            raise EntryError(
                f"entries {by_name[entry['method']]} and {path} name the same method {entry['method']!r}"
            )
        by_name[entry["method"]] = path
        entries.append(entry | {"file": path.name, "path": str(path)})
    return entries
