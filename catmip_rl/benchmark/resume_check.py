"""What a resumed grid (``catmip bench suite``, ``catmip bench paper --resume``) checks in a run's folder
before it reads the results back instead of playing them: everything it can recompute, as strictly as
the run that wrote them.

* One run's files: its record (run.json, each file's SHA-256; a folder without one is not trusted), its
  summary and episodes as :mod:`~catmip_rl.benchmark.results_check` checks a compared result.
* This job's run: every episode names the job's method, setting (task, communication, SLAM noise,
  longest macro-action), seed and its own index; summary.json's setting and horizon are the setting's;
  the maps are those this installation generates for the task and seed (the frozen manifest's).
* What was computed from the episodes is what they give: summary.json's numbers (successes, means,
  decisions, stalls, bytes) and curve.csv's success curves.

Results of another setting on the same maps, relabelled with every file made to fit (its record too),
hold nothing that tells them apart short of playing them again: the leaderboard's ``--replay`` does that
for an entry. Each failure is a ValueError of one line naming the folder or the file.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from catmip_env.engines.episode_stats import success_curve
from catmip_rl.benchmark.results_check import check_counts, check_csv, episode_ticks, summary_fields

if TYPE_CHECKING:
    from catmip_rl.evaluation.evaluate import EvalSetting

__all__ = ["read_summary", "check_resumed"]

AGAIN = "remove the folder to play the run again"


def read_summary(folder: Path) -> dict[str, Any]:
    """The JSON object in ``folder``'s summary.json; ValueError naming the file for one that cannot be
    read, is not JSON or holds something else than an object."""
    path = folder / "summary.json"
    summary = _read_json(path)
    if not isinstance(summary, dict):
        raise ValueError(
            f"{path} holds a JSON {type(summary).__name__}, not a run's summary (an object): {AGAIN}"
        )
    return summary


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as err:  # unreadable, not UTF-8, not JSON
        raise ValueError(
            f"{path} is not readable JSON ({type(err).__name__}: {' '.join(str(err).split())[:200]}): {AGAIN}"
        ) from None


def check_resumed(folder: Path, setting: EvalSetting, seed: int, episodes: int, method: str) -> None:
    """ValueError unless ``folder`` holds one run's complete results of ``method`` on ``episodes`` maps of
    ``seed`` in ``setting``, each number in it what its episodes give (the module's checks)."""
    from catmip_rl.store.outputs import RECORD, check_record

    if check_record(folder) is None:
        raise ValueError(
            f"{folder} holds results without their record ({RECORD}): they cannot be trusted as one run's; "
            "remove the folder to play it again"
        )
    summary = read_summary(folder)
    rows = _read_json(folder / "episodes.json")
    _label, _method, horizon, _seed = summary_fields(folder, summary, None)
    maps, ticks = episode_ticks(folder, rows, horizon)
    check_counts(folder, summary, ticks, horizon)
    check_csv(folder, maps, ticks)
    if len(maps) != episodes:
        raise ValueError(f"{folder} holds {len(maps)} episodes, not the {episodes} its grid plays")
    _check_played(folder, summary, rows, setting, seed, method)
    _check_maps(folder, maps, setting.task, seed)
    rescue = np.nan_to_num(ticks, nan=-1.0)
    sampled = _column(folder, rows, "sampled_rescue_tick", tick=True)
    _check_numbers(folder, summary, rows, rescue, sampled, horizon)
    _check_curve(folder, rescue, sampled, horizon)


def _check_played(
    folder: Path, summary: dict[str, Any], rows: list[dict], setting: EvalSetting, seed: int, method: str
) -> None:
    """Every episode is ``method``'s in ``setting`` on ``seed``, its index in order; the summary's setting
    and horizon are ``setting``'s."""
    want = {"method": method, **asdict(setting), "seed": seed}
    for e, row in enumerate(rows):
        for key, value in (*want.items(), ("episode", e)):
            found = row.get(key)
            if key not in row or found != value or isinstance(found, bool) != isinstance(value, bool):
                said = f"no {key}" if key not in row else f"{key} {found!r}"
                raise ValueError(
                    f"{folder / 'episodes.json'}: episode {e} has {said}, not this run's {value!r} "
                    f"(another run's results): {AGAIN}"
                )
    if summary.get("setting", asdict(setting)) != asdict(setting):  # absent: a summary older than the key
        raise ValueError(
            f"{folder / 'summary.json'}: setting {summary.get('setting')!r} is not this run's "
            f"{asdict(setting)!r}: {AGAIN}"
        )
    horizon = setting.env_config().horizon_ticks
    if summary["horizon"] != horizon:
        raise ValueError(
            f"{folder / 'summary.json'}: horizon {summary['horizon']!r} is not {setting.label}'s ({horizon} "
            f"ticks): {AGAIN}"
        )


def _check_maps(folder: Path, maps: list[str], task: str, seed: int) -> None:
    """``maps`` are maps 0 .. E-1 that this installation generates for ``task`` and ``seed``."""
    from catmip_env.maps.map_sets import check_maps, map_hashes

    try:
        report = check_maps(task, seed, maps)
        if report.status != "verified" and maps != map_hashes(task, seed, len(maps)):
            raise ValueError("differs")
    except ValueError:
        raise ValueError(
            f"{folder} holds episodes on other maps than maps 0 .. {len(maps) - 1} of {task}, "
            f"seed {seed}: play it again"
        ) from None


def _column(folder: Path, rows: list[dict], key: str, tick: bool = False) -> np.ndarray | None:
    """Column ``key`` of the episodes as floats (a tick column: -1 for null), None where an episode has
    none; ValueError naming the episode for a value that is not a finite number (a tick: a whole one
    >= 0, or null)."""
    if not all(key in row for row in rows):
        return None
    out = np.empty(len(rows))
    for e, row in enumerate(rows):
        value = row[key]
        if tick and value is None:
            out[e] = -1
            continue
        number = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        if not number or (tick and (value < 0 or not float(value).is_integer())):
            expected = "a whole number of ticks or null" if tick else "a finite number"
            raise ValueError(
                f"{folder / 'episodes.json'}: episode {e} has {key} {value!r}: expected {expected}"
            )
        out[e] = value
    return out


def _mean(values: np.ndarray) -> float | None:
    return float(values.mean()) if len(values) else None


def _recomputed(
    folder: Path, rows: list[dict], rescue: np.ndarray, sampled: np.ndarray | None, horizon: int
) -> dict[str, Any]:
    """The summary's numbers that the episodes give (as ``catmip_env.engines.episode_stats`` and ``evaluate``
    compute them; -1: a tick that never came), for the columns the episodes hold."""
    col = {key: _column(folder, rows, key) for key in ("explored_fraction", "decisions", "stalls")}
    col |= {key: _column(folder, rows, key) for key in ("bytes_embedding", "bytes_raw")}
    found = _column(folder, rows, "target_found_tick", tick=True)
    informed = _column(folder, rows, "rescuer_informed_tick", tick=True)
    n, rescued = len(rows), rescue >= 0
    out: dict[str, Any] = {"mean_rescue_tick": _mean(rescue[rescued])}
    if found is not None:
        out |= {
            "mean_target_found_tick": _mean(found[found >= 0]),
            "target_found_rate": float((found >= 0).mean()),
        }
    if found is not None and informed is not None:
        known = informed >= 0
        out["mean_found_to_informed_ticks"] = _mean((informed - found)[known])
        out["mean_informed_to_rescue_ticks"] = _mean((rescue - informed)[rescued & known])
    if col["explored_fraction"] is not None:
        out["mean_explored_fraction"] = float(col["explored_fraction"].mean())
    if col["decisions"] is not None:
        decisions = float(col["decisions"].sum())
        out |= {"decisions": decisions, "decisions_per_episode": decisions / n}
        for kind in ("embedding", "raw"):
            if col[f"bytes_{kind}"] is not None:
                out[f"bytes_per_decision_{kind}"] = float(col[f"bytes_{kind}"].sum()) / max(decisions, 1)
    if col["stalls"] is not None:
        out["stalls_per_episode"] = float(col["stalls"].sum()) / n
    if sampled is not None:
        curve = success_curve(sampled.astype(np.int64), horizon)
        out["sampled_success_rate"] = float(curve[-1])
        out["sampled_success_by_100"] = float(curve[min(100, horizon)])
        out["sampled_mean_rescue_tick"] = _mean(sampled[sampled >= 0])
    return out


def _close(stated: Any, value: float | None) -> bool:
    if stated is None or value is None:
        return stated is None and value is None
    number = isinstance(stated, (int, float)) and not isinstance(stated, bool)
    return number and math.isclose(stated, value, rel_tol=1e-6, abs_tol=1e-9)  # a float32 mean, summed


def _check_numbers(
    folder: Path,
    summary: dict[str, Any],
    rows: list[dict],
    rescue: np.ndarray,
    sampled: np.ndarray | None,
    horizon: int,
) -> None:
    """summary.json states every number its episodes give, as they give it."""
    for key, value in _recomputed(folder, rows, rescue, sampled, horizon).items():
        if key not in summary or not _close(summary[key], value):
            said = f"says {key} {summary[key]!r}" if key in summary else f"has no {key}"
            raise ValueError(
                f"{folder / 'summary.json'} {said}, but episodes.json gives {json.dumps(value)}: {AGAIN}"
            )


def _check_curve(folder: Path, rescue: np.ndarray, sampled: np.ndarray | None, horizon: int) -> None:
    """curve.csv is the success curve of the episodes (and of their sampled pass where they have one):
    one row per tick 0 .. horizon."""
    path = folder / "curve.csv"
    try:
        with open(path, newline="") as f:
            table = list(csv.DictReader(f))
    except (OSError, UnicodeDecodeError, csv.Error) as err:
        raise ValueError(f"{path} is not readable ({type(err).__name__}: {err}): {AGAIN}") from None
    curves = {"success_rate": success_curve(rescue.astype(np.int64), horizon)}
    if sampled is not None:
        curves["sampled_success_rate"] = success_curve(sampled.astype(np.int64), horizon)
    columns = set(table[0]) if table else set()
    if len(table) != horizon + 1 or columns != {"tick", *curves}:
        raise ValueError(
            f"{path} is not the success curve of episodes.json: {len(table)} rows of {sorted(columns)}, "
            f"not {horizon + 1} of {sorted({'tick', *curves})}: {AGAIN}"
        )
    for t, row in enumerate(table):
        for key, curve in curves.items():
            if not (_float(row["tick"]) == t and _close(_float(row[key]), float(curve[t]))):
                raise ValueError(
                    f"{path}: tick {row['tick']!r} has {key} {row[key]!r}, but episodes.json gives "
                    f"{curve[t]:.6g} at tick {t}: {AGAIN}"
                )


def _float(text: str | None) -> float | None:
    try:
        return float(text)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None
