"""The leaderboard (``catmip leaderboard``): suite entries checked, optionally replayed, then ranked in a
table and a figure.

Every entry is checked first (:mod:`~catmip_rl.benchmark.entry_check`: the suite, the split, the frozen
maps, every number recomputed from its rescue ticks); with ``replay`` (``--replay K``) the first K maps
of every setting and training run are played again from the files the entry names
(:mod:`~catmip_rl.benchmark.replay`) and an entry whose ticks differ is refused. The table ranks the
test split's entries by the IQM of success by tick 100; an entry level with the one above it (their
paired difference over the settings has a 95 % CI that holds 0, :func:`level_with`) shares its rank.
A validation table (``--split validation``, for choosing) orders its entries the same way but ranks none.
Each row shows its class (planner, learned, hybrid, floor) and whether it was verified by replay.

Every entry played the same maps, so any two compare map by map: :func:`paired_rows` (``catmip
leaderboard --vs METHOD``) gives each entry's difference from one reference in every setting.
"""

from __future__ import annotations

import csv
import io
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from catmip_env.map_sets import SPLITS
from catmip_rl.benchmark.entry import CLASSES, EPISODES, SETTINGS, SUITE
from catmip_rl.benchmark.entry_check import EntryError, load_entries
from catmip_rl.evaluation.stats import CONFIDENCE, shared_maps_cis
from catmip_rl.store.files import atomic_savefig, atomic_write_text

__all__ = [
    "EntryError",
    "load_entries",
    "leaderboard_rows",
    "level_with",
    "paired_rows",
    "paired_names",
    "render_leaderboard",
    "md_text",
    "task_table",
]

SHORT = {"full": "full", "4": "σ4", "2": "σ2"}  # column headings: T2 σ2 +n
LONG = {"full": "full", "4": "σ = 4", "2": "σ = 2"}  # a task's table: σ = 2 + noise
CLASS_COLOURS = {"planner": "tab:blue", "learned": "tab:green", "hybrid": "tab:purple", "floor": "tab:gray"}
LEVEL_RESAMPLES = 4_000
RANKED_SPLIT = "test"  # a validation table orders its entries for choosing; only the test split ranks


def _short(label: str) -> str:
    st = next(s for s in SETTINGS if s.label == label)
    return f"T{st.task[-1]} {SHORT[st.comm]}" + (" +n" if st.noise else "")


def md_text(text: str) -> str:
    """``text`` as a Markdown table cell shows it and nothing more: no cell break (``|``), link, code,
    emphasis or HTML (entries hold no control characters: checked). An underscore inside a word stays
    as it is (``amat_general``: no emphasis there)."""
    text = re.sub(r"([\\`*\[\]<>|~])", r"\\\1", text)
    return re.sub(r"(?<![A-Za-z0-9])_|_(?![A-Za-z0-9])", r"\\_", text)


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
    """One row per entry, best aggregate first: rank (shared with the row above when level with it,
    :func:`level_with`), method, class, runs, actions, the IQM of success by tick 100 over (runs ×
    settings) with its 95 % CI, each setting's success by tick 100, verified (maps replayed per setting,
    0: not replayed), what it was chosen on, code and notes."""
    rows = []
    for e in sorted(entries, key=lambda e: -e["checked"]["iqm"]):
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
            "verified": e.get("replayed", 0),
            "chosen_on": e.get("chosen_on") or "",
            "success": checked["success"],
        }
        row |= {st.label: checked["settings"][st.label]["success_by_100"] for st in SETTINGS}
        rows.append(row | {"code": e.get("code") or "", "notes": e.get("notes") or ""})
    for k, row in enumerate(rows):
        row["rank"] = k + 1
        if k:
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


def _page_head(title: str, text: str, head: list[str]) -> list[str]:
    """A Markdown page's title, its paragraph and its table's heading rows."""
    return [f"# {title}", "", text, "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]


def _maps(episodes: int, split: str) -> str:
    return f"{episodes} {split} maps (seed {SPLITS[split]}) per setting"


def _paired_markdown(rows: list[dict[str, Any]], vs: str, episodes: int, split: str) -> str:
    head = ["method", "class", "runs", "ahead / behind", *(_short(s.label) for s in SETTINGS)]
    lines = _page_head(
        f"CATMiP suite {SUITE} ({split} split): each method against {md_text(vs)}",
        f"Success by tick 100 less {md_text(vs)}'s on the same {_maps(episodes, split)}, with a 95 % CI "
        "over the maps and the method's training runs (the reference's runs averaged per map); bold where "
        "the interval excludes 0. Ahead / behind: the settings whose interval lies above / below 0. "
        "Recomputed from the entries' rescue ticks (`catmip leaderboard --vs`).",
        head,
    )
    for r in rows:
        cells = [md_text(r["method"]), r["class"], str(r["runs"]), f"{r['ahead']} / {r['behind']}"]
        for st in SETTINGS:
            diff, low, high = r[st.label]
            cell = f"{diff:+.3f} [{low:+.3f}, {high:+.3f}]"
            cells.append(f"**{cell}**" if low > 0 or high < 0 else cell)
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _paired_csv(rows: list[dict[str, Any]], vs: str) -> str:
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["method", "class", "vs", "runs", "setting", "diff_success_by_100", "ci_low", "ci_high"])
    for r in rows:
        for st in SETTINGS:
            diff, low, high = r[st.label]
            writer.writerow(
                [r["method"], r["class"], vs, r["runs"], st.label, f"{diff:.6f}", f"{low:.6f}", f"{high:.6f}"]
            )
    return out.getvalue()


def _verified(row: dict[str, Any]) -> str:
    return f"✓ {row['verified']} maps" if row["verified"] else "not replayed"


def _markdown(rows: list[dict[str, Any]], episodes: int, split: str) -> str:
    head = ["rank", "method", "class", "runs", "actions", "IQM by tick 100 [95 % CI]"]
    head += [_short(s.label) for s in SETTINGS] + ["verified"]
    ranked = split == RANKED_SPLIT  # a validation table shows "–" for every rank
    ranking = (
        "A rank shared with the row above: the two are level (their paired difference over the settings "
        "has a 95 % CI that holds 0)."
        if ranked
        else f"Not ranked (–): the {split} split is for choosing; the leaderboard ranks the "
        f"{RANKED_SPLIT} split's entries, each played once after every choice is frozen."
    )
    lines = _page_head(
        f"CATMiP leaderboard, suite {SUITE} ({split} split)",
        f"Success by tick 100 on {_maps(episodes, split)}; the aggregate is the IQM over (training runs "
        f"× settings) with a 95 % CI over runs and maps. {ranking} Class: planner; "
        "learned (plays from its own observations); hybrid (reads a planner at play time); floor (no "
        "skill). T2/T3: Task 2 (20×20, 3 robots) / Task 3 (32×32, 6 robots); full / σ4 / σ2: "
        "communication; +n: 5 % SLAM noise. Every number is recomputed from the entry's rescue ticks; "
        "verified: the first maps of every setting and run replayed from the entry's files gave its "
        "ticks (`catmip leaderboard --replay K`).",
        head,
    )
    for r in rows:
        method = md_text(r["method"])
        if r["code"]:
            method = f"[{method}](<{r['code']}>)"
        cells = [
            str(r["rank"]) if ranked else "–",
            method,
            r["class"],
            str(r["runs"]),
            md_text(r["actions"]),
            f"**{r['iqm']:.3f}** [{r['iqm_ci_low']:.3f}, {r['iqm_ci_high']:.3f}]",
            *(f"{r[s.label]:.2f}" for s in SETTINGS),
            _verified(r),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    about = []
    for r in rows:
        said = [md_text(r["notes"])] if r["notes"] else []
        said += [f"chosen on: {md_text(r['chosen_on'])}"] if r["chosen_on"] else []
        if said:
            about.append(f"- **{md_text(r['method'])}** ({r['class']}): " + "; ".join(said))
    return "\n".join(lines + ([""] + about if about else [])) + "\n"


def task_table(rows: list[dict[str, Any]], task: str) -> str:
    """One task's Markdown table (``task2`` / ``task3``): a row per entry of :func:`leaderboard_rows`, in
    its order, with the class, the method and success by tick 100 in each of the task's settings (the
    test-split tables of the task pages, ``docs/figures/test_tables.py``)."""
    settings = [st for st in SETTINGS if st.task == task]
    if not settings:
        tasks = sorted({st.task for st in SETTINGS})
        raise ValueError(f"the suite has no {task!r} settings (its tasks: {', '.join(tasks)})")
    head = ["class", "method", *(LONG[st.comm] + (" + noise" if st.noise else "") for st in settings)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        plain = re.fullmatch(r"[A-Za-z0-9_.:+-]+", r["method"])  # as code; any other name as plain text
        name = f"`{r['method']}`" if plain else md_text(r["method"])
        lines.append("| " + " | ".join([r["class"], name, *(f"{r[st.label]:.2f}" for st in settings)]) + " |")
    return "\n".join(lines)


def _figure(rows: list[dict[str, Any]], path: Path, episodes: int, split: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    n = len(rows)
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 2.0 + 0.36 * n), width_ratios=[1, 2.2], sharey=True)
    y = np.arange(n)[::-1]
    for yk, r in zip(y, rows):
        colour = CLASS_COLOURS[r["class"]]
        err = [[r["iqm"] - r["iqm_ci_low"]], [r["iqm_ci_high"] - r["iqm"]]]
        left.errorbar(
            r["iqm"],
            yk,
            xerr=err,
            fmt="o",
            color=colour,
            markersize=3.5,
            elinewidth=2.5,
            capsize=5,
            capthick=1.5,
        )
    ranked = split == RANKED_SPLIT
    labels = [
        (f"{r['rank']}. " if ranked else "") + r["method"][:28] + (" ✓" if r["verified"] else "")
        for r in rows
    ]
    left.set_yticks(y, labels)
    for tick, r in zip(left.get_yticklabels(), rows):
        tick.set_color(CLASS_COLOURS[r["class"]])
    lows, highs = [r["iqm_ci_low"] for r in rows], [r["iqm_ci_high"] for r in rows]
    span = max(max(highs) - min(lows), 0.05)
    left.set_xlim(max(0.0, min(lows) - 0.06 * span), min(1.0, max(highs) + 0.06 * span))
    left.set_xlabel("IQM, rescued by tick 100 (95 % CI)")
    left.grid(axis="x", alpha=0.3)
    used = [c for c in CLASSES if any(r["class"] == c for r in rows)]
    left.legend(
        [Line2D([], [], color=CLASS_COLOURS[c], marker="o", lw=2.5) for c in used],
        used,
        loc="best",
        fontsize=8,
        title="class",
        title_fontsize=8,
    )
    grid = np.array([[r[s.label] for s in SETTINGS] for r in rows])
    image = right.imshow(
        grid, aspect="auto", cmap="viridis", vmin=0, vmax=1, extent=(-0.5, len(SETTINGS) - 0.5, -0.5, n - 0.5)
    )
    for i, row in enumerate(grid):
        for j, v in enumerate(row):
            colour = "white" if v < 0.6 else "black"
            right.text(j, y[i], f"{v:.2f}", ha="center", va="center", fontsize=7, color=colour)
    right.set_xticks(range(len(SETTINGS)), [_short(s.label) for s in SETTINGS], rotation=45, ha="right")
    fig.colorbar(image, ax=right, label="rescued by tick 100")
    verified = "; ✓ verified by replay" if any(r["verified"] for r in rows) else ""
    unranked = "" if ranked else " (not ranked: for choosing)"
    fig.suptitle(f"CATMiP suite {SUITE}, {split} split{unranked}: {episodes} maps per setting{verified}")
    fig.tight_layout()
    return atomic_savefig(fig, path, dpi=150)


def paired_names(vs: str) -> tuple[str, str]:
    """The file names of the comparison with ``vs`` (``vs_NAME.md`` and ``.csv``)."""
    stem = "vs_" + re.sub(r"[^A-Za-z0-9_.-]+", "_", vs)
    return f"{stem}.md", f"{stem}.csv"


def _link(code: str, folder: Path, out: Path) -> str:
    """An entry's ``code`` as the page in ``out`` links it: a web address as it is; a relative path (from
    the entries ``folder``, e.g. ``../../examples/mappo_torchrl.py``) made relative to ``out``."""
    if not code or "://" in code:
        return code
    return Path(os.path.relpath((folder / code).resolve(), out.resolve())).as_posix()


def render_leaderboard(
    folder: str | Path,
    out: str | Path,
    episodes: int = EPISODES,
    vs: str | None = None,
    split: str = "test",
    replay: int = 0,
    progress: bool = False,
) -> list[Path]:
    """Check every entry in ``folder`` (all of ``split``), replay the first ``replay`` maps of each
    (:func:`~catmip_rl.benchmark.replay.replay_entry`; 0: none), and write ``out/leaderboard.md`` and
    ``out/leaderboard.png`` and, given ``vs``, every other entry against it (:func:`paired_rows`) to
    ``out/vs_NAME.md`` / ``.csv``; returns the files' paths. Nothing is written unless every entry is
    accepted (and replays to its ticks) and ``vs`` is one."""
    entries = load_entries(folder, episodes, split)
    if replay:
        from catmip_rl.benchmark.replay import replay_entry

        for e in entries:
            e["replayed"] = replay_entry(e, replay, progress=progress)
    out = Path(out)
    rows = [r | {"code": _link(r["code"], Path(folder), out)} for r in leaderboard_rows(entries)]
    paired = paired_rows(entries, vs) if vs is not None else None
    out.mkdir(parents=True, exist_ok=True)
    md = out / "leaderboard.md"
    atomic_write_text(md, _markdown(rows, episodes, split))
    paths = [md, _figure(rows, out / "leaderboard.png", episodes, split)]
    if paired is not None:
        md_name, csv_name = paired_names(vs)
        atomic_write_text(out / md_name, _paired_markdown(paired, vs, episodes, split))
        atomic_write_text(out / csv_name, _paired_csv(paired, vs))
        paths += [out / md_name, out / csv_name]
    return paths
