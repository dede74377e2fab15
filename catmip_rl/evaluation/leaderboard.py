"""The leaderboard (``catmip leaderboard``): suite entries checked, then ranked in a table and a figure.

An entry (``catmip bench suite``, :func:`~catmip_rl.evaluation.suite.make_entry`) is accepted only if
it is one of this suite: its format and version, the held-out seed and every map of it, every setting
and no other, its maps' digest equal to the frozen maps' (``catmip_env/frozen_maps``), one list of
rescue ticks per training run and map, and every number it states equal to the number recomputed from
those ticks. The table's numbers and intervals are the leaderboard's own recomputation, not the
entry's. A refused entry is one line naming its file and the first problem (:class:`EntryError`).

Every entry played the same maps, so any two compare map by map: :func:`paired_rows` (``catmip
leaderboard --vs METHOD``) gives each entry's difference from one reference in every setting.
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from catmip_rl.evaluation.evaluate import EvalSetting
from catmip_rl.evaluation.stats import shared_maps_cis
from catmip_rl.evaluation.suite import (
    BY_TICK,
    ENTRY_FORMAT,
    EPISODES,
    SETTINGS,
    SPLITS,
    SUITE,
    iqm_interval,
    split_digest,
    rescued_by_100,  # fmt: skip
    setting_numbers,
)
from catmip_rl.files import atomic_savefig, atomic_write_text

__all__ = [
    "EntryError", "check_entry", "load_entries", "leaderboard_rows", "paired_rows", "paired_names",
    "render_leaderboard",
]  # fmt: skip

SHORT = {"full": "full", "4": "σ4", "2": "σ2"}  # column headings: T2 σ2 +n


class EntryError(ValueError):
    """An entry the leaderboard refuses (the message names the file and the problem)."""


def _short(label: str) -> str:
    st = next(s for s in SETTINGS if s.label == label)
    return f"T{st.task[-1]} {SHORT[st.comm]}" + (" +n" if st.noise else "")


def _ticks(entry: dict[str, Any], label: str, horizon: int, episodes: int) -> np.ndarray:
    ticks = entry["settings"][label].get("rescue_tick")
    runs = len(entry["runs"])
    if not isinstance(ticks, list) or len(ticks) != runs:
        raise ValueError(f"{label}: rescue_tick must hold one list per training run ({runs})")
    for run in ticks:
        if not isinstance(run, list) or len(run) != episodes or not all(type(t) is int for t in run):
            raise ValueError(f"{label}: each run's rescue_tick must be {episodes} integers (one per map)")
    array = np.array(ticks, np.int64)
    if array.min() < -1 or array.max() > horizon:
        raise ValueError(f"{label}: rescue ticks must be -1 (not rescued) or 0 .. {horizon}")
    return array


def _same(stated: Any, recomputed: float | None) -> bool:
    if recomputed is None or stated is None:
        return stated is None and recomputed is None
    return isinstance(stated, (int, float)) and math.isclose(stated, recomputed, rel_tol=0, abs_tol=1e-9)


def check_entry(entry: Any, episodes: int = EPISODES) -> dict[str, Any]:
    """The leaderboard's numbers of ``entry`` (aggregate and per setting, recomputed from its ticks, and
    ``success``: per setting whether each run rescued each map by tick 100, (runs, maps)); ValueError
    naming the first thing that makes it no entry of this suite."""
    _check_header(entry, episodes)
    numbers, success = {}, {}
    for st in SETTINGS:
        ticks, horizon = _setting_ticks(entry, st, episodes)
        numbers[st.label] = setting_numbers(ticks, horizon, intervals=False)  # the table shows the means
        stated = entry["settings"][st.label]
        for key in ("success_by_100", "success_rate", "mean_rescue_tick"):
            if not _same(stated.get(key), numbers[st.label][key]):
                raise ValueError(
                    f"{st.label}: {key} {stated.get(key)!r} is not what its rescue ticks give "
                    f"({numbers[st.label][key]!r})"
                )
        success[st.label] = rescued_by_100(ticks, horizon)
    iqm, low, high = iqm_interval(list(success.values()))
    if not _same((entry.get("aggregate") or {}).get("iqm_success_by_100"), iqm):
        raise ValueError(f"aggregate iqm_success_by_100 is not what its rescue ticks give ({iqm!r})")
    return {"iqm": iqm, "iqm_ci": [low, high], "settings": numbers, "success": success}


def _check_header(entry: Any, episodes: int) -> None:
    """ValueError unless ``entry`` is an entry of this suite (format, suite, seed, episodes), names a
    method and its training runs, and holds every setting of the suite and no other."""
    if not isinstance(entry, dict) or entry.get("format") != ENTRY_FORMAT:
        raise ValueError(f"not a {ENTRY_FORMAT} file")
    split = entry.get("split")
    if split not in SPLITS:
        raise ValueError(f"split is {split!r}, not one of {sorted(SPLITS)}")
    for key, want in (("suite", SUITE), ("seed", SPLITS[split]), ("episodes", episodes)):
        if entry.get(key) != want:
            raise ValueError(f"{key} is {entry.get(key)!r}, the leaderboard's is {want!r}")
    if not isinstance(entry.get("method"), str) or not entry["method"].strip():
        raise ValueError("it names no method")
    if not isinstance(entry.get("runs"), list) or not entry["runs"]:
        raise ValueError("it lists no training run")
    settings = entry.get("settings")
    labels = [st.label for st in SETTINGS]
    if not isinstance(settings, dict):
        raise ValueError("it has no settings")
    missing, extra = [s for s in labels if s not in settings], sorted(set(settings) - set(labels))
    if missing or extra:
        problem = f"missing setting(s) {missing}" if missing else f"setting(s) not in suite {SUITE}: {extra}"
        raise ValueError(problem)


def _setting_ticks(entry: dict[str, Any], st: EvalSetting, episodes: int) -> tuple[np.ndarray, int]:
    """The rescue ticks ``(runs, episodes)`` and horizon of setting ``st`` of ``entry``; ValueError
    unless the setting is the suite's (task, communication, noise, macro-action length, frozen maps)."""
    stated = entry["settings"][st.label]
    if not isinstance(stated, dict):
        raise ValueError(f"{st.label}: not an object")
    for key in ("task", "comm", "noise", "max_ma_ticks"):
        if stated.get(key) != getattr(st, key):
            suite_value = getattr(st, key)
            raise ValueError(f"{st.label}: {key} is {stated.get(key)!r}, the suite's is {suite_value!r}")
    if stated.get("maps_sha256") != split_digest(st.task, entry["split"], episodes):
        raise ValueError(
            f"{st.label}: its maps are not the frozen {entry['split']} maps (maps_sha256 differs)"
        )
    horizon = stated.get("horizon")
    if type(horizon) is not int or horizon < BY_TICK:
        raise ValueError(f"{st.label}: horizon {horizon!r} is not a horizon of the suite")
    return _ticks(entry, st.label, horizon, episodes), horizon


def load_entries(folder: str | Path, episodes: int = EPISODES) -> list[dict[str, Any]]:
    """Every ``*.json`` entry in ``folder``, checked (:func:`check_entry`), with the leaderboard's numbers
    under ``"checked"``; :class:`EntryError` naming the first bad file, or an empty or missing folder."""
    folder = Path(folder)
    if not folder.is_dir():
        raise EntryError(f"no such folder of entries: {folder}")
    paths = sorted(folder.glob("*.json"))
    if not paths:
        raise EntryError(f"no entries (*.json) in {folder}")
    entries = []
    for path in paths:
        try:
            entry = json.loads(path.read_text())
            entry["checked"] = check_entry(entry, episodes)
        except (OSError, json.JSONDecodeError) as err:
            raise EntryError(f"entry {path}: unreadable ({err})") from None
        except (ValueError, TypeError, KeyError) as err:
            raise EntryError(f"entry {path} refused: {err}") from None
        entries.append(entry | {"file": path.name})
    names = [e["method"] for e in entries]
    if len(set(names)) != len(names):
        twice = sorted({n for n in names if names.count(n) > 1})
        raise EntryError(f"two entries name the same method: {twice}")
    return entries


def leaderboard_rows(entries: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per entry, best aggregate first: method, runs, actions, the IQM of success by tick 100
    over (runs × settings) with its 95 % CI, each setting's success by tick 100, code and notes."""
    rows = []
    for e in entries:
        checked = e["checked"]
        low, high = checked["iqm_ci"]
        row = {"method": e["method"], "runs": len(e["runs"]), "actions": e.get("actions") or "",
               "iqm": checked["iqm"], "iqm_ci_low": low, "iqm_ci_high": high}  # fmt: skip
        row |= {st.label: checked["settings"][st.label]["success_by_100"] for st in SETTINGS}
        rows.append(row | {"code": e.get("code") or "", "notes": e.get("notes") or ""})
    return sorted(rows, key=lambda r: -r["iqm"])


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
        for row in others for st in SETTINGS
    ]  # fmt: skip
    intervals = iter(zip(diffs, shared_maps_cis(diffs)))  # every entry played the same maps
    rows = []
    for row in others:
        out = {"method": row["method"], "runs": row["runs"], "ahead": 0, "behind": 0}
        for st in SETTINGS:
            diff, (low, high) = next(intervals)
            out[st.label] = (float(diff.mean()), low, high)
            out["ahead"] += low > 0
            out["behind"] += high < 0
        rows.append(out)
    return rows


def _page_head(title: str, text: str, head: list[str]) -> list[str]:
    """A Markdown page's title, its paragraph and its table's heading rows."""
    return [f"# {title}", "", text, "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]


def _paired_markdown(rows: list[dict[str, Any]], vs: str, episodes: int) -> str:
    head = ["method", "runs", "ahead / behind", *(_short(s.label) for s in SETTINGS)]
    lines = _page_head(
        f"CATMiP suite {SUITE}: each method against {vs}",
        f"Success by tick 100 less {vs}'s on the same {episodes} test maps (seed {SPLITS['test']}) per setting, "
        "with a 95 % CI over the maps and the method's training runs (the reference's runs averaged per "
        "map); bold where the interval excludes 0. Ahead / behind: the settings whose interval lies above "
        "/ below 0. Recomputed from the entries' rescue ticks (`catmip leaderboard --vs`).",
        head,
    )
    for r in rows:
        cells = [r["method"], str(r["runs"]), f"{r['ahead']} / {r['behind']}"]
        for st in SETTINGS:
            diff, low, high = r[st.label]
            cell = f"{diff:+.3f} [{low:+.3f}, {high:+.3f}]"
            cells.append(f"**{cell}**" if low > 0 or high < 0 else cell)
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _paired_csv(rows: list[dict[str, Any]], vs: str) -> str:
    lines = ["method,vs,runs,setting,diff_success_by_100,ci_low,ci_high"]
    for r in rows:
        for st in SETTINGS:
            diff, low, high = r[st.label]
            lines.append(f"{r['method']},{vs},{r['runs']},{st.label},{diff:.6f},{low:.6f},{high:.6f}")
    return "\n".join(lines) + "\n"


def _markdown(rows: list[dict[str, Any]], episodes: int) -> str:
    head = ["rank", "method", "runs", "actions", "IQM by tick 100 [95 % CI]"]
    head += [_short(s.label) for s in SETTINGS]
    lines = _page_head(
        f"CATMiP leaderboard, suite {SUITE}",
        f"Success by tick 100 on {episodes} test maps (seed {SPLITS['test']}) per setting; the aggregate is the "
        "IQM over (training runs × settings) with a 95 % CI over runs and maps. T2/T3: Task 2 (20×20, 3 "
        "robots) / Task 3 (32×32, 6 robots); full / σ4 / σ2: communication; +n: 5 % SLAM noise. Every "
        "number is recomputed from the entry's rescue ticks (`catmip leaderboard`).",
        head,
    )
    for k, r in enumerate(rows, 1):
        method = f"[{r['method']}]({r['code']})" if r["code"] else r["method"]
        cells = [str(k), method, str(r["runs"]), r["actions"],
                 f"**{r['iqm']:.3f}** [{r['iqm_ci_low']:.3f}, {r['iqm_ci_high']:.3f}]",
                 *(f"{r[s.label]:.2f}" for s in SETTINGS)]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    notes = [f"- **{r['method']}**: {r['notes']}" for r in rows if r["notes"]]
    return "\n".join(lines + ([""] + notes if notes else [])) + "\n"


def _figure(rows: list[dict[str, Any]], path: Path, episodes: int) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(rows)
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 1.8 + 0.35 * n), width_ratios=[1, 2.2], sharey=True)
    y = np.arange(n)[::-1]
    iqm = np.array([r["iqm"] for r in rows])
    err = np.array([[r["iqm"] - r["iqm_ci_low"] for r in rows], [r["iqm_ci_high"] - r["iqm"] for r in rows]])
    left.errorbar(iqm, y, xerr=err, fmt="o", color="black", capsize=3)
    left.set_yticks(y, [r["method"] for r in rows])
    left.set_xlabel("IQM, rescued by tick 100")
    left.set_xlim(0, 1)
    left.grid(axis="x", alpha=0.3)
    grid = np.array([[r[s.label] for s in SETTINGS] for r in rows])
    image = right.imshow(grid, aspect="auto", cmap="viridis", vmin=0, vmax=1,
                         extent=(-0.5, len(SETTINGS) - 0.5, -0.5, n - 0.5))  # fmt: skip
    for i, row in enumerate(grid):
        for j, v in enumerate(row):
            colour = "white" if v < 0.6 else "black"
            right.text(j, y[i], f"{v:.2f}", ha="center", va="center", fontsize=7, color=colour)
    right.set_xticks(range(len(SETTINGS)), [_short(s.label) for s in SETTINGS], rotation=45, ha="right")
    fig.colorbar(image, ax=right, label="rescued by tick 100")
    fig.suptitle(f"CATMiP suite {SUITE}: {episodes} test maps per setting")
    fig.tight_layout()
    return atomic_savefig(fig, path, dpi=150)


def paired_names(vs: str) -> tuple[str, str]:
    """The file names of the comparison with ``vs`` (``vs_NAME.md`` and ``.csv``)."""
    stem = "vs_" + re.sub(r"[^A-Za-z0-9_.-]+", "_", vs)
    return f"{stem}.md", f"{stem}.csv"


def _link(code: str, folder: Path, out: Path) -> str:
    """An entry's ``code`` as the page in ``out`` links it: a URL as it is; a path (relative to the
    entries ``folder``, e.g. ``../../examples/mappo_torchrl.py``) made relative to ``out``."""
    if not code or "://" in code or Path(code).is_absolute():
        return code
    return Path(os.path.relpath((folder / code).resolve(), out.resolve())).as_posix()


def render_leaderboard(
    folder: str | Path, out: str | Path, episodes: int = EPISODES, vs: str | None = None
) -> list[Path]:
    """Check every entry in ``folder`` and write ``out/leaderboard.md`` and ``out/leaderboard.png`` and,
    given ``vs``, every other entry against it (:func:`paired_rows`) to ``out/vs_NAME.md`` / ``.csv``;
    returns the files' paths. Nothing is written unless every entry is accepted and ``vs`` is one."""
    entries = load_entries(folder, episodes)
    out = Path(out)
    rows = [r | {"code": _link(r["code"], Path(folder), out)} for r in leaderboard_rows(entries)]
    paired = paired_rows(entries, vs) if vs is not None else None
    out.mkdir(parents=True, exist_ok=True)
    md = out / "leaderboard.md"
    atomic_write_text(md, _markdown(rows, episodes))
    paths = [md, _figure(rows, out / "leaderboard.png", episodes)]
    if paired is not None:
        md_name, csv_name = paired_names(vs)
        atomic_write_text(out / md_name, _paired_markdown(paired, vs, episodes))
        atomic_write_text(out / csv_name, _paired_csv(paired, vs))
        paths += [out / md_name, out / csv_name]
    return paths
