"""The leaderboard (``catmip leaderboard``): suite entries checked, verified, then ranked in a table and a
figure (the page: :mod:`~catmip_rl.benchmark.board_page`).

Every entry is checked first (:mod:`~catmip_rl.benchmark.entry_check`: the suite, the split, the frozen
maps, every number recomputed from its rescue ticks); a file that fails is refused and listed under the
table, the others stay on the board, and an entry of fewer maps is a preview, placed against the board on
the same maps but not ranked. With ``--replay K`` (and ``--fresh M``) every entry is verified
(:mod:`~catmip_rl.benchmark.verify`: maps replayed from its files, fresh maps against its claim) and the
record is written beside the page; without, the page renders from that record. The table ranks the test
split's entries by the IQM of success by tick 100; an entry level with the one above it (their paired
difference over the settings has a 95 % CI that holds 0, :func:`level_with`) shares its rank. A
validation table (``--split validation``, for choosing) orders its entries the same way but ranks none.
Each row shows its class (planner, learned, hybrid, floor) and what its verification found.

Every entry played the same maps, so any two compare map by map: :func:`paired_rows` (``catmip
leaderboard --vs METHOD``) gives each entry's difference from one reference in every setting.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from catmip_rl.benchmark.board_page import (
    page_figure,
    page_markdown,
    paired_csv,
    paired_markdown,
    paired_names,
)
from catmip_rl.benchmark.entry import EPISODES, SETTINGS
from catmip_rl.benchmark.entry_check import EntryError, load_board, load_entries
from catmip_rl.evaluation.stats import CONFIDENCE, shared_maps_cis
from catmip_rl.store.files import atomic_write_text

__all__ = [
    "EntryError",
    "load_entries",
    "leaderboard_rows",
    "level_with",
    "paired_rows",
    "render_leaderboard",
    "preview_rows",
    "read_record",
    "Board",
]

LEVEL_RESAMPLES = 4_000


def level_with(
    upper: dict[str, np.ndarray], lower: dict[str, np.ndarray], seed: int = 0
) -> tuple[float, float, float]:
    """The paired difference ``upper - lower`` in success by tick 100 pooled over the settings (each
    setting's per-map difference of the runs' means, averaged over maps and settings) with its 95 % CI:
    each resample draws every task's maps with replacement, alike for its settings (they share maps)."""
    rng = np.random.default_rng(seed)
    diffs = {label: upper[label].mean(axis=0) - lower[label].mean(axis=0) for label in upper}
    draws = np.zeros(LEVEL_RESAMPLES)
    for task in sorted({st.task for st in SETTINGS}):
        labels = [st.label for st in SETTINGS if st.task == task]
        per_map = np.mean([diffs[label] for label in labels], axis=0)  # (maps,) over the task's settings
        picks = rng.integers(per_map.size, size=(LEVEL_RESAMPLES, per_map.size))
        draws += per_map[picks].mean(axis=1) * len(labels)
    draws /= len(SETTINGS)
    point = float(np.mean([d.mean() for d in diffs.values()]))
    low, high = np.quantile(draws, [(1 - CONFIDENCE) / 2, (1 + CONFIDENCE) / 2])
    return point, float(low), float(high)


def leaderboard_rows(entries: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per entry, best aggregate first, the reference rows (class ``reference``: the headroom)
    after the ranked ones with rank None: rank (shared with the row above when level with it,
    :func:`level_with`), method, class, runs, actions, the IQM of success by tick 100 over (runs ×
    settings) with its 95 % CI, each setting's success by tick 100, verified (maps replayed per setting,
    0: not replayed), what it was chosen on, code and notes."""
    rows = []
    order = sorted(entries, key=lambda e: (e["class"] == "reference", -e["checked"]["iqm"]))
    for e in order:
        checked = e["checked"]
        low, high = checked["iqm_ci"]
        row = {
            "method": e["method"],
            "class": e["class"],
            "runs": len(e["runs"]),
            "actions": e.get("actions") or "",
            "iqm": checked["iqm"],
            "iqm_ci_low": low,
            "iqm_ci_high": high,
            "verified": e.get("verified"),
            "class_note": e.get("class_note", ""),
            "chosen_on": e.get("chosen_on") or "",
            "success": checked["success"],
        }
        row |= {st.label: checked["settings"][st.label]["success_by_100"] for st in SETTINGS}
        rows.append(row | {"code": e.get("code") or "", "notes": e.get("notes") or ""})
    for k, row in enumerate(rows):
        row["rank"] = k + 1
        if row["class"] == "reference":  # the headroom, never ranked
            row["rank"] = None
        elif k:
            above = rows[k - 1]
            row["vs_above"] = level_with(above["success"], row["success"])
            if row["vs_above"][1] <= 0:  # the interval holds 0 (or lies below): level with the row above
                row["rank"] = above["rank"]
    return rows


def paired_rows(entries: list[dict[str, Any]], vs: str) -> list[dict[str, Any]]:
    """Every entry but ``vs`` against the entry of method ``vs`` on the same maps, in the leaderboard's
    order: per setting the difference in success by tick 100 (its runs' success on a map less the
    reference's mean over its runs on that map) with a 95 % CI over the maps and the entry's training
    runs (:func:`~catmip_rl.evaluation.stats.shared_maps_cis`), and how many settings' intervals lie
    above and below 0. :class:`EntryError` if no entry is ``vs``."""
    by_name = {e["method"]: e for e in entries}
    if vs not in by_name:
        raise EntryError(f"--vs {vs!r} is no entry's method; the entries are {sorted(by_name)}")
    reference = {label: s.mean(axis=0) for label, s in by_name[vs]["checked"]["success"].items()}
    others = leaderboard_rows([e for e in entries if e["method"] != vs])
    diffs = [
        by_name[row["method"]]["checked"]["success"][st.label] - reference[st.label]
        for row in others
        for st in SETTINGS
    ]
    intervals = iter(zip(diffs, shared_maps_cis(diffs)))  # every entry played the same maps
    rows = []
    for row in others:
        out = {"method": row["method"], "class": row["class"], "runs": row["runs"], "ahead": 0, "behind": 0}
        for st in SETTINGS:
            diff, (low, high) = next(intervals)
            out[st.label] = (float(diff.mean()), low, high)
            out["ahead"] += low > 0
            out["behind"] += high < 0
        rows.append(out)
    return rows


def preview_rows(entries: list[dict[str, Any]], previews: list[dict[str, Any]]) -> list[list[dict[str, Any]]]:
    """Per preview (an entry of fewer maps a setting): the board's entries and the preview, each on the
    first N maps of every setting (the preview's N), in the leaderboard's order; the preview's row
    marked ``preview`` (N), no rank."""
    from catmip_rl.benchmark.entry import iqm_interval

    tables = []
    for p in previews:
        n = p["episodes"]
        cut = []
        for e in entries:
            success = {label: s[:, :n] for label, s in e["checked"]["success"].items()}
            iqm, low, high = iqm_interval(list(success.values()))
            settings = {label: {"success_by_100": float(s.mean())} for label, s in success.items()}
            checked = {"iqm": iqm, "iqm_ci": [low, high], "settings": settings, "success": success}
            cut.append(e | {"checked": checked})
        rows = leaderboard_rows([*cut, p])
        for r in rows:
            r["preview"] = n if r["method"] == p["method"] else 0
        tables.append(rows)
    return tables


def _link(code: str, folder: Path, out: Path) -> str:
    """An entry's ``code`` as the page in ``out`` links it: a web address as it is; a relative path (from
    the entries ``folder``, e.g. ``../../examples/mappo_torchrl.py``) made relative to ``out``."""
    if not code or "://" in code:
        return code
    return Path(os.path.relpath((folder / code).resolve(), out.resolve())).as_posix()


class Board(list):
    """The files :func:`render_leaderboard` wrote (a list of paths), with the entries it ``refused``
    (``(file, one line)``) and what it says it ``could_not`` verify here."""

    refused: list[tuple[str, str]]
    could_not: list[tuple[str, str]]


def read_record(path: Path) -> dict[str, Any] | None:
    """A verification record (:mod:`~catmip_rl.benchmark.verify`) at ``path``, None if there is none;
    EntryError for one that is not a record."""
    from catmip_rl.benchmark.verify import RECORD_FORMAT

    if not path.exists():
        return None
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise EntryError(f"{path} is no verification record ({' '.join(str(err).split())[:120]})") from None
    if not isinstance(record, dict) or record.get("format") != RECORD_FORMAT:
        raise EntryError(f"{path} is no {RECORD_FORMAT} file")
    return record


def _apply_record(entries: list[dict[str, Any]], record: dict[str, Any] | None) -> tuple[list, list]:
    """Mark each entry with what ``record`` says of it (only if the record saw this very file: its
    SHA-256); returns the entries left on the board and the refusals and 'cannot verify here' notes."""
    from catmip_rl.store.shipped import file_sha256

    kept, refused, could_not = [], [], []
    for e in entries:
        said = (record or {}).get("entries", {}).get(e["method"])
        if said is None or said.get("sha256") != file_sha256(e["path"]):
            kept.append(e)
            continue
        if said["outcome"] == "refused":
            refused.append((e["file"], said["reason"]))
            continue
        if said["outcome"] != "verified":
            could_not.append((e["file"], said["reason"]))
            kept.append(e)
            continue
        runs = said["runs"]
        replayed = min((len(v) for r in runs for v in r.get("replayed", {}).values()), default=0)
        fresh = [r["pooled"] for r in runs if r.get("pooled")]
        e["verified"] = {
            "replayed": replayed,
            "fresh": record.get("fresh", 0),
            "played": float(np.mean([p["played"] for p in fresh])) if fresh else None,
            "claimed": float(np.mean([p["claimed"] for p in fresh])) if fresh else None,
        }
        if said.get("class") and said["class"] != e["class"]:
            e["class"], e["class_note"] = said["class"], said.get("class_note", "")
        kept.append(e)
    return kept, refused, could_not


def _known(path: Path) -> frozenset[str]:
    """The methods a record already at ``path`` says were verified: the originals of any copy (an entry
    copied under a new name is not among them); none where there is no readable record."""
    try:
        record = read_record(path)
    except EntryError:
        return frozenset()
    said = (record or {}).get("entries")
    if not isinstance(said, dict):
        return frozenset()
    return frozenset(m for m, s in said.items() if isinstance(s, dict) and s.get("outcome") == "verified")


def render_leaderboard(
    folder: str | Path,
    out: str | Path,
    episodes: int = EPISODES,
    vs: str | None = None,
    split: str = "test",
    replay: int | None = 0,
    progress: bool = False,
    fresh: int = 0,
    seed: int | None = None,
    jobs: int = 1,
    record: str | Path | None = None,
    backend: str = "local",
    ray_address: str | None = None,
) -> Board:
    """Check every entry in ``folder`` (all of ``split``), verify them (``replay`` maps of each setting
    and run, None: all; ``fresh`` fresh maps a setting; ``seed``: the verification's, drawn now if None;
    :func:`~catmip_rl.benchmark.verify.verify_board`, on ``jobs`` workers of ``backend``) and write
    ``out/verification.json``; or, verifying nothing, read the record at ``record`` (default
    ``out/verification.json`` where there is one). Then write ``out/leaderboard.md`` and
    ``out/leaderboard.png`` and, given ``vs``, every other entry against it (:func:`paired_rows`) to
    ``out/vs_NAME.md`` / ``.csv``; returns the files' paths (:class:`Board`). A refused entry is listed
    under the table with its reason, never ranked."""
    from catmip_rl.benchmark.record_check import check_record
    from catmip_rl.benchmark.verify import RECORD, verify_board

    entries, previews, refused = load_board(folder, episodes, split)
    out = Path(out)
    if replay != 0 or fresh:
        known = _known(out / RECORD)
        found = verify_board(
            entries + previews, replay, fresh, seed, jobs, progress, known, backend, ray_address
        )
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_text(out / RECORD, json.dumps(found, indent=1) + "\n")
    else:
        where = Path(record) if record is not None else out / RECORD
        found = read_record(where)
        if found is not None:
            try:
                check_record(found, entries + previews)
            except (ValueError, TypeError, KeyError) as err:
                why = " ".join(str(err).split())[:300]
                raise EntryError(
                    f"{where} is not what a check of these entries writes ({why}): verify again "
                    "(catmip leaderboard --replay K) or remove it"
                ) from None
    entries, gone, could_not = _apply_record(entries, found)
    previews, gone_too, could_not_too = _apply_record(previews, found)
    refused += gone + gone_too
    rows = [r | {"code": _link(r["code"], Path(folder), out)} for r in leaderboard_rows(entries)]
    paired = paired_rows(entries, vs) if vs is not None else None
    out.mkdir(parents=True, exist_ok=True)
    md = out / "leaderboard.md"
    about = {"refused": refused, "could_not": could_not + could_not_too, "record": found}
    atomic_write_text(md, page_markdown(rows, episodes, split, about, preview_rows(entries, previews)))
    paths = Board([md, page_figure(rows, out / "leaderboard.png", episodes, split)])
    if paired is not None:
        md_name, csv_name = paired_names(vs)
        atomic_write_text(out / md_name, paired_markdown(paired, vs, episodes, split))
        atomic_write_text(out / csv_name, paired_csv(paired, vs))
        paths += [out / md_name, out / csv_name]
    paths.refused, paths.could_not = refused, about["could_not"]
    return paths
