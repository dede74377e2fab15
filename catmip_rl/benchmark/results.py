"""Result folders read back for :mod:`~catmip_rl.benchmark.compare`: one method's results
(:class:`Result`, by :func:`load_results`), what each was played on (:func:`played_on`: the setting, the
map seed, the horizon and the maps' digest), and :func:`check_alike`, which refuses in one line results
not played alike. What is read is checked first (:mod:`~catmip_rl.benchmark.results_check`)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from catmip_rl.benchmark.entry import maps_digest
from catmip_rl.benchmark.results_check import (
    check_counts,
    check_csv,
    episode_ticks,
    episodes_digest,
    summary_fields,
)
from catmip_rl.store.outputs import check_record

__all__ = ["Result", "PlayedOn", "played_on", "check_alike", "load_results"]


@dataclass
class Result:
    """One ``catmip eval`` result folder."""

    path: Path
    method: str
    setting: str  # the setting's label, e.g. task2-sigma4-noise0-ma10
    seed: int
    maps: list[str]  # map hash of each episode
    success: np.ndarray  # (E,) bool rescued by tick 100 (or the horizon)
    rescue_tick: np.ndarray  # (E,) float, nan where not rescued
    digest: str = ""  # results_check.episodes_digest of episodes.json: equal for a copied folder
    recorded: bool = True  # its files checked against its run.json (False: written before records)
    horizon: int | None = None  # summary.json's horizon (None: a result built by hand)


@dataclass(frozen=True)
class PlayedOn:
    """What a result was played on: two results can be paired map by map exactly when these are equal."""

    setting: str  # the setting's label: task, communication, SLAM noise, longest macro-action
    seed: int  # the map seed (the suite's splits: validation 1000, test 20261201)
    horizon: int | None
    episodes: int
    maps_sha256: str  # of the map hashes in play order, as a suite entry's maps_sha256

    def describe(self) -> str:
        from catmip_env.maps.map_sets import SPLITS

        split = next((f" ({name} split)" for name, s in SPLITS.items() if s == self.seed), "")
        horizon = "" if self.horizon is None else f", horizon {self.horizon}"
        return (
            f"{self.setting}, seed {self.seed}{split}{horizon}, {self.episodes} maps "
            f"sha256 {self.maps_sha256[:12]}"
        )


def played_on(result: Result) -> PlayedOn:
    """What ``result`` was played on: its setting, map seed, horizon and the digest of the maps its
    episodes played (computed from their map hashes, never taken from a summary)."""
    digest = maps_digest(result.maps)  # the digest a suite entry states
    return PlayedOn(result.setting, result.seed, result.horizon, len(result.maps), digest)


ADVICE = (
    "give every method the same settings, --seed and --episodes, or pass --unpaired to show them "
    "side by side marked unpaired"
)


def _unlike(a: Result, pa: PlayedOn, b: Result, pb: PlayedOn | None) -> str:
    """One line: ``a`` played ``pa`` and ``b`` played ``pb`` (None: ``b``'s method has nothing there)."""
    if pb is None:
        return (
            f"{a.path} ({a.method}: {pa.describe()}) and {b.path} ({b.method}) were not played alike "
            f"({b.method} has no result in {pa.setting} on those maps)"
        )
    keys = ("setting", "seed", "horizon", "maps_sha256")
    fields = [k.removesuffix("_sha256") for k in keys if getattr(pa, k) != getattr(pb, k)]
    differ = ", ".join(fields[:-1]) + (" and " if len(fields) > 1 else "") + fields[-1]
    return (
        f"{a.path} ({a.method}: {pa.describe()}) and {b.path} ({b.method}: {pb.describe()}) were not "
        f"played alike (they differ in {differ})"
    )


def check_alike(results: list[Result], unpaired: bool = False) -> None:
    """ValueError (one line naming two folders, what each played and what differs) unless the runs of
    each method played the same in each setting and, without ``unpaired``, every method played the same
    (:func:`played_on`) as every other: the same settings, each on the same seed, horizon and maps."""
    by_method: dict[str, dict[PlayedOn, Result]] = {}
    first: dict[tuple[str, str], tuple[PlayedOn, Result]] = {}
    for r in results:
        p = played_on(r)
        seen = first.setdefault((r.method, r.setting), (p, r))
        if seen[0] != p:
            raise ValueError(
                _unlike(seen[1], seen[0], r, p) + f": the runs of one method ({r.method}) must play the same "
                "maps (give each the same --seed and --episodes)"
            )
        by_method.setdefault(r.method, {}).setdefault(p, r)
    if unpaired:
        return
    ref_plays, *others = by_method.values()
    for plays in others:
        if set(plays) == set(ref_plays):
            continue
        a_only = [p for p in ref_plays if p not in plays]
        b_only = [p for p in plays if p not in ref_plays]
        same = [(pa, pb) for pa in a_only for pb in b_only if pa.setting == pb.setting]
        if same or (a_only and b_only):
            pa, pb = same[0] if same else (a_only[0], b_only[0])
            message = _unlike(ref_plays[pa], pa, plays[pb], pb)
        elif a_only:
            message = _unlike(ref_plays[a_only[0]], a_only[0], next(iter(plays.values())), None)
        else:
            message = _unlike(plays[b_only[0]], b_only[0], next(iter(ref_plays.values())), None)
        raise ValueError(f"{message}, so they cannot be compared map by map; {ADVICE}")


def _load_one(folder: Path, name: str | None) -> Result:
    """The result in ``folder``, checked: one run's files (its record, :func:`~catmip_rl.store.outputs.
    check_record`), and consistent (:mod:`~catmip_rl.benchmark.results_check`)."""
    record = check_record(folder)
    try:
        summary = json.loads((folder / "summary.json").read_text())
        rows = json.loads((folder / "episodes.json").read_text())
    except (OSError, ValueError) as err:  # unreadable, not UTF-8, not JSON
        raise ValueError(
            f"{folder} is not a readable catmip eval result ({type(err).__name__}: {err})"
        ) from None
    label, method, horizon, seed = summary_fields(folder, summary, name)
    maps, ticks = episode_ticks(folder, rows, horizon)
    check_counts(folder, summary, ticks, horizon)
    check_csv(folder, maps, ticks)
    with np.errstate(invalid="ignore"):
        success = ticks <= min(100, horizon)
    digest, recorded = episodes_digest(rows), record is not None
    return Result(folder, method, label, seed, maps, success, ticks, digest, recorded, horizon)


def load_results(specs: list[str]) -> list[Result]:
    """The results under each ``DIR`` or ``NAME=DIR[,DIR...]`` of ``specs``; ValueError on a path
    without results, a corrupt one or one given twice (one line naming it)."""
    results = []
    given: set[Path] = set()
    for spec in specs:
        name, sep, paths = spec.partition("=")
        if not sep:
            name, paths = None, spec
        elif not name.strip():
            raise ValueError(f"{spec!r}: the name before = is empty (write NAME=DIR[,DIR...])")
        for p in (s for s in paths.split(",") if s.strip()):
            root = Path(p.strip())
            if not root.exists():
                raise FileNotFoundError(f"no such result folder: {root}")
            found = sorted(
                s.parent for s in root.rglob("summary.json") if (s.parent / "episodes.json").exists()
            )
            if not found:
                raise ValueError(
                    f"{root} holds no catmip eval result (a folder with summary.json and episodes.json)"
                )
            for f in found:
                if f.resolve() in given:
                    raise ValueError(f"{f} is given twice: each result folder counts once")
                given.add(f.resolve())
                results.append(_load_one(f, name.strip() if name else None))
    return results
