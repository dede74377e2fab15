"""The checks ``catmip compare`` makes on what it reads, each failure a ValueError of one line naming the
folder or file and the problem.

* One result folder (what ``EvalResult.write`` wrote): summary.json's ``label`` / ``method`` are
  strings, ``horizon`` / ``seed`` whole numbers (:func:`summary_fields`); episodes.json holds at least
  one episode, each on another map, with a rescue tick that is null or a whole number from 0 to the
  horizon (and not after the episode's ``ticks``), and ``rescued`` true exactly when there is one
  (:func:`episode_ticks`); summary.json's ``episodes``, ``success_rate`` and ``success_by_100`` count
  the same episodes (:func:`check_counts`), and so does episodes.csv where there is one (:func:`check_csv`).
  Optional keys are checked where they are present.
* The results compared together (:func:`check_runs`): two results of one method that hold the same
  episodes (the same maps, every column the same but the method's name: :func:`episodes_digest`) are
  one run copied, not two training runs.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["summary_fields", "episode_ticks", "check_counts", "check_csv", "episodes_digest", "check_runs"]


def _whole(value: Any) -> bool:
    """A whole number as JSON gives it: an int, or a float without fraction (never a bool, nan or inf)."""
    if isinstance(value, bool):
        return False
    return isinstance(value, int) or (isinstance(value, float) and value.is_integer())


def summary_fields(folder: Path, summary: Any, name: str | None) -> tuple[str, str, int, int]:
    """The ``label``, method (``name`` if given, else summary.json's ``method``), ``horizon`` and ``seed``
    of ``folder``'s summary.json (``summary``, parsed)."""
    where = folder / "summary.json"
    if not isinstance(summary, dict):
        raise ValueError(f"{where} is not a JSON object (it holds a {type(summary).__name__})")
    for key in ("label", "horizon", "seed") + (() if name else ("method",)):
        if key not in summary:
            raise ValueError(f"{folder} is not a readable catmip eval result (summary.json has no {key!r})")
    label, method = summary["label"], name or summary["method"]
    for key, value in (("label", label), ("method", summary.get("method", method))):
        if not isinstance(value, str) or not value.strip():
            raise ValueError(f"{where}: {key} is {value!r}: expected a non-empty string")
    horizon, seed = summary["horizon"], summary["seed"]
    if not _whole(horizon) or horizon < 1:
        raise ValueError(f"{where}: horizon is {horizon!r}: expected a whole number of ticks >= 1")
    if not _whole(seed):
        raise ValueError(f"{where}: seed is {seed!r}: expected a whole number")
    return label, method, int(horizon), int(seed)


def _tick(at: str, key: str, value: Any, horizon: int) -> int | None:
    """``value`` of column ``key`` as a tick of the episode ``at`` names: None (not rescued) or 0..horizon."""
    if value is None:
        return None
    if not _whole(value):
        raise ValueError(f"{at} has {key} {value!r}: expected a whole number of ticks or null")
    if value < 0:
        raise ValueError(f"{at} has {key} {value}: a tick is never negative")
    if value > horizon:
        raise ValueError(f"{at} has {key} {value}, beyond the horizon ({horizon} ticks)")
    return int(value)


def _episode_tick(at: str, row: dict[str, Any], horizon: int) -> int | None:
    """The rescue tick of the episode ``row`` (``at`` names it): None (not rescued) or 0..horizon, with
    ``sampled_rescue_tick``, ``rescued`` and ``ticks`` (the episode's length) agreeing where present."""
    if "rescue_tick" not in row:
        raise ValueError(f"{at} has no rescue_tick")
    tick = _tick(at, "rescue_tick", row["rescue_tick"], horizon)
    _tick(at, "sampled_rescue_tick", row.get("sampled_rescue_tick"), horizon)
    rescued = row.get("rescued", tick is not None)
    if not isinstance(rescued, bool):
        raise ValueError(f"{at} has rescued {rescued!r}: expected true or false")
    if rescued != (tick is not None):
        said = "rescued" if rescued else "not rescued"
        raise ValueError(f"{at} says {said} but its rescue_tick is {json.dumps(tick)}")
    if "ticks" in row:  # the episode's length: it ends at the rescue or the horizon
        length = row["ticks"]
        if not _whole(length) or not 0 <= length <= horizon:
            raise ValueError(f"{at} has ticks {length!r}: expected a whole number from 0 to {horizon}")
        if tick is not None and tick > length:
            raise ValueError(f"{at} has rescue_tick {tick} after its end (ticks {int(length)})")
    return tick


def episode_ticks(folder: Path, rows: Any, horizon: int) -> tuple[list[str], np.ndarray]:
    """The map hash and rescue tick (``(E,)`` float, nan where not rescued) of each episode of
    ``folder``'s episodes.json (``rows``, parsed)."""
    where = folder / "episodes.json"
    if not isinstance(rows, list):
        raise ValueError(f"{where} is not a list of episodes (it holds a {type(rows).__name__})")
    if not rows:
        raise ValueError(f"{where} holds no episodes: a result needs at least one")
    maps: list[str] = []
    ticks: list[float] = []
    first: dict[str, int] = {}
    for e, row in enumerate(rows):
        if not isinstance(row, dict):
            raise ValueError(f"{where}: episode {e} is a {type(row).__name__}, not an object")
        h = row.get("map_hash")
        if not isinstance(h, str) or not h:
            raise ValueError(f"{where}: episode {e} has map_hash {h!r}: expected a non-empty string")
        if h in first:
            raise ValueError(
                f"{where}: map {h} is played twice (episodes {first[h]} and {e}): "
                "each episode of a result is another map"
            )
        first[h] = e
        tick = _episode_tick(f"{where}: episode {e} (map {h})", row, horizon)
        maps.append(h)
        ticks.append(math.nan if tick is None else float(tick))
    return maps, np.array(ticks, float)


def check_counts(folder: Path, summary: dict[str, Any], ticks: np.ndarray, horizon: int) -> None:
    """summary.json's ``episodes``, ``success_rate`` and ``success_by_100`` (where present) count the
    episodes of episodes.json (``ticks``: their rescue ticks, nan where not rescued)."""
    n = len(ticks)
    said = summary.get("episodes", n)
    if not _whole(said) or said != n:
        raise ValueError(f"{folder}: summary.json says {said!r} episodes but episodes.json holds {n}")
    by = min(100, horizon)
    with np.errstate(invalid="ignore"):
        counts = {
            "success_rate": ("", int((~np.isnan(ticks)).sum())),
            "success_by_100": (f" by tick {by}", int((ticks <= by).sum())),
        }
    for key, (when, count) in counts.items():
        if key not in summary:
            continue
        rate = summary[key]
        number = isinstance(rate, (int, float)) and not isinstance(rate, bool)
        if not number or not abs(rate * n - count) < 0.5:  # not the same count (nan fails too)
            raise ValueError(
                f"{folder}: summary.json says {key} {rate!r} but episodes.json has {count} of its {n} "
                f"episodes rescued{when} ({count / n:.4g})"
            )


def _same_tick(text: str | None, tick: float) -> bool:
    if text is None:  # no such column
        return True
    if text.strip() == "":
        return math.isnan(tick)
    try:
        return float(text) == tick
    except ValueError:
        return False


def check_csv(folder: Path, maps: list[str], ticks: np.ndarray) -> None:
    """``folder``'s episodes.csv, where there is one, holds the episodes of episodes.json (``maps``,
    ``ticks``): as many, with the same map hash and rescue tick in each row."""
    path = folder / "episodes.csv"
    if not path.exists():
        return
    try:
        with open(path, newline="") as f:
            table = list(csv.DictReader(f))
    except (OSError, UnicodeDecodeError, csv.Error) as err:
        raise ValueError(f"{path} is not readable ({type(err).__name__}: {err})") from None
    if len(table) != len(maps):
        raise ValueError(
            f"{folder}: episodes.csv holds {len(table)} episodes but episodes.json holds {len(maps)}"
        )
    for e, (row, h, tick) in enumerate(zip(table, maps, ticks)):
        if row.get("map_hash", h) != h or not _same_tick(row.get("rescue_tick"), tick):
            json_tick = "null" if math.isnan(tick) else int(tick)
            raise ValueError(
                f"{folder}: episodes.csv and episodes.json differ at episode {e}: map {row.get('map_hash')} "
                f"rescue_tick {row.get('rescue_tick') or 'empty'} vs map {h} rescue_tick {json_tick}"
            )


def episodes_digest(rows: list[dict[str, Any]]) -> str:
    """SHA-256 of the episodes without their method's name: equal for a copy of the folder (renamed or
    not) and, for different policies, different in practice (the explored fraction, the decisions...)."""
    rows = [{k: v for k, v in row.items() if k != "method"} for row in rows]
    return hashlib.sha256(json.dumps(rows, sort_keys=True).encode()).hexdigest()


def check_runs(results: Sequence[Any]) -> None:
    """Each of ``results`` (``results.Result``) has episodes, one per map, and no two results of one
    method hold the same episodes (the same digest, or with none the same maps and rescue ticks)."""
    seen: dict[tuple[str, Any], Any] = {}
    for r in results:
        n = len(r.maps)
        if n == 0:
            raise ValueError(f"{r.path}: the result holds no episodes: a result needs at least one")
        if len(r.success) != n or len(r.rescue_tick) != n:
            raise ValueError(
                f"{r.path}: {n} maps but {len(r.success)} success flags and {len(r.rescue_tick)} rescue ticks"
            )
        if len(set(r.maps)) != n:
            twice = next(h for h in r.maps if r.maps.count(h) > 1)
            raise ValueError(
                f"{r.path}: map {twice} is played twice: each episode of a result is another map"
            )
        episodes = r.digest or (tuple(r.maps), tuple(np.nan_to_num(r.rescue_tick, nan=-1.0)))
        if (r.method, episodes) in seen:
            other = seen[r.method, episodes]
            raise ValueError(
                f"{other.path} and {r.path} hold the same results: a copy is not a second training run"
            )
        seen[r.method, episodes] = r
