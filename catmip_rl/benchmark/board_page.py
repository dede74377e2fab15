"""The leaderboard's page (``catmip leaderboard``'s files): the ranked table in Markdown with what its
verification record says (:mod:`~catmip_rl.benchmark.verify`) -- the verified column, the fresh maps'
played-vs-claimed, the refused entries and those this machine cannot verify under the table, the
previews placed against the board -- its figure, the paired comparison with one entry, and one task's
table for the task pages. The rows come from :func:`~catmip_rl.benchmark.leaderboard.leaderboard_rows`.
"""

from __future__ import annotations

import csv
import io
import re
from pathlib import Path
from typing import Any

import numpy as np

from catmip_env.maps.map_sets import SPLITS
from catmip_rl.benchmark.entry import CLASSES, SETTINGS, SUITE
from catmip_rl.store.files import atomic_savefig

__all__ = [
    "md_text",
    "task_table",
    "board_top",
    "page_markdown",
    "page_figure",
    "paired_markdown",
    "paired_csv",
    "paired_names",
    "RANKED_SPLIT",
]

RANKED_SPLIT = "test"  # a validation table orders its entries for choosing; only the test split ranks

SHORT = {"full": "full", "4": "σ4", "2": "σ2"}  # column headings: T2 σ2 +n


LONG = {"full": "full", "4": "σ = 4", "2": "σ = 2"}  # a task's table: σ = 2 + noise


CLASS_COLOURS = {
    "planner": "tab:blue",
    "learned": "tab:green",
    "hybrid": "tab:purple",
    "floor": "tab:gray",
    "reference": "tab:red",
}


def _short(label: str) -> str:
    st = next(s for s in SETTINGS if s.label == label)
    return f"T{st.task[-1]} {SHORT[st.comm]}" + (" +n" if st.noise else "")


def md_text(text: str) -> str:
    """``text`` as a Markdown table cell shows it and nothing more: no cell break (``|``), link, code,
    emphasis or HTML (entries hold no control characters: checked). An underscore inside a word stays
    as it is (``amat_general``: no emphasis there)."""
    text = re.sub(r"([\\`*\[\]<>|~])", r"\\\1", text)
    return re.sub(r"(?<![A-Za-z0-9])_|_(?![A-Za-z0-9])", r"\\_", text)


def _page_head(title: str, text: str, head: list[str]) -> list[str]:
    """A Markdown page's title, its paragraph and its table's heading rows."""
    return [f"# {title}", "", text, "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]


def _maps(episodes: int, split: str) -> str:
    return f"{episodes} {split} maps (seed {SPLITS[split]}) per setting"


def paired_markdown(rows: list[dict[str, Any]], vs: str, episodes: int, split: str) -> str:
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


def paired_csv(rows: list[dict[str, Any]], vs: str) -> str:
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
    v = row["verified"]
    if not v:
        return "not verified"
    said = [f"{v['replayed']} replayed"] if v["replayed"] else []
    return "✓ " + ", ".join(said + ([f"{v['fresh']} fresh"] if v["fresh"] else []))


def _fresh(row: dict[str, Any]) -> str:
    v = row["verified"]
    return "–" if not v or v["played"] is None else f"{v['played']:.2f} vs {v['claimed']:.2f}"


def _record_text(record: dict[str, Any] | None) -> str:
    if not record:
        return "Not verified: no record of a check (`catmip leaderboard --replay K --fresh M`)."
    replay = record["replay"]
    return (
        f"Verified on {record['created'][:10]} with catmip {record['versions'].get('catmip')} "
        f"({record['machine'].get('cpu_capability')}), seed {record['seed']}: {replay} maps a setting "
        f"and run replayed from the entry's files (chosen by the seed), and {record['fresh']} fresh maps a "
        "setting (a map set of that seed, drawn from the operating system when the check ran) played "
        "and compared with the entry's claim by the fresh-map rule (docs/verification.md); "
        "`verification.json` beside this page holds every map and number."
    )


def page_markdown(
    rows: list[dict[str, Any]],
    episodes: int,
    split: str,
    about: dict[str, Any] | None = None,
    previews: list[dict[str, Any]] | None = None,
) -> str:
    about = about or {}
    record = about.get("record")
    fresh = record["fresh"] if record and record.get("fresh") else 0
    head = ["rank", "method", "class", "runs", "actions", "IQM by tick 100 [95 % CI]"]
    head += (
        [_short(s.label) for s in SETTINGS]
        + ["verified"]
        + ([f"fresh {fresh}: played vs claimed"] if fresh else [])
    )
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
        "communication; +n: 5 % SLAM noise. Every number is recomputed from the entry's rescue ticks. "
        + _record_text(record),
        head,
    )
    ranked_rows = [r for r in rows if r["class"] != "reference"]
    for r in ranked_rows:
        lines.append("| " + " | ".join(_cells(r, ranked) + ([_fresh(r)] if fresh else [])) + " |")
    lines += _reference_markdown([r for r in rows if r["class"] == "reference"], head, fresh)
    notes = []
    for r in ranked_rows:
        said = [md_text(r["notes"])] if r["notes"] else []
        said += [f"chosen on: {md_text(r['chosen_on'])}"] if r["chosen_on"] else []
        said += [md_text(r["class_note"])] if r.get("class_note") else []
        if said:
            notes.append(f"- **{md_text(r['method'])}** ({r['class']}): " + "; ".join(said))
    text = lines + ([""] + notes if notes else [])
    for title, items in (("Refused", about.get("refused")), ("Cannot verify here", about.get("could_not"))):
        if items:
            text += ["", f"**{title}** ({len(items)}):", ""]
            text += [f"- `{md_text(name)}`: {md_text(reason)}" for name, reason in items]
    if previews:
        text += ["", *_preview_markdown(previews)]
    return "\n".join(text) + "\n"


def _reference_markdown(rows: list[dict[str, Any]], head: list[str], fresh: int) -> list[str]:
    """The reference rows' table under the ranked one (none: nothing), each defined in one line."""
    from catmip_env.planners.reference import REFERENCES

    if not rows:
        return []
    lines = [
        "",
        "**Reference rows** (not ranked): project code that reads the true world, to show how far the "
        "ranked rows are from the ceiling; replayed and checked like every entry.",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    lines += ["| " + " | ".join(_cells(r, False) + ([_fresh(r)] if fresh else [])) + " |" for r in rows]
    said = [r["method"] for r in rows if r["method"] in REFERENCES]
    return lines + ["", *(f"- `{m}`: {REFERENCES[m][2]}" for m in said)]


def _cells(r: dict[str, Any], ranked: bool) -> list[str]:
    method = md_text(r["method"])
    if r["code"]:
        method = f"[{method}](<{r['code']}>)"
    return [
        str(r["rank"]) if ranked and not r.get("preview") else "–",
        method + (f" (preview, {r['preview']} maps)" if r.get("preview") else ""),
        r["class"],
        str(r["runs"]),
        md_text(r["actions"]),
        f"**{r['iqm']:.3f}** [{r['iqm_ci_low']:.3f}, {r['iqm_ci_high']:.3f}]",
        *(f"{r[s.label]:.2f}" for s in SETTINGS),
        _verified(r),
    ]


def _preview_markdown(tables: list[list[dict[str, Any]]]) -> list[str]:
    lines = []
    for rows in tables:
        mine = next(r for r in rows if r["preview"])
        lines += [
            f"**Preview: {md_text(mine['method'])}** on the first {mine['preview']} maps of every setting, "
            "placed against the board's entries on the same maps (not ranked among full entries):",
            "",
            "| rank | method | class | runs | actions | IQM by tick 100 [95 % CI] | "
            + " | ".join(_short(s.label) for s in SETTINGS)
            + " | verified |",
            "|" + "---|" * (7 + len(SETTINGS)),
        ]
        lines += ["| " + " | ".join(_cells(r | {"code": ""}, False)) + " |" for r in rows]
        lines.append("")
    return lines


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


def board_top(rows: list[dict[str, Any]], top: int = 6) -> str:
    """The top of the board for the README: the first ``top`` ranked rows (rank, method, class, IQM by tick
    100 with its 95 % CI) and, under them, the reference rows (the headroom), from
    :func:`~catmip_rl.benchmark.leaderboard.leaderboard_rows` of the test split."""
    lines = ["| rank | method | class | IQM by tick 100 [95 % CI] |", "|---|---|---|---|"]
    ranked = [r for r in rows if r["class"] != "reference"][:top]
    refs = [r for r in rows if r["class"] == "reference"]
    for r in ranked + refs:
        rank = str(r["rank"]) if r["rank"] else "–"
        iqm = f"{r['iqm']:.3f} [{r['iqm_ci_low']:.3f}, {r['iqm_ci_high']:.3f}]"
        lines.append(f"| {rank} | `{md_text(r['method'])}` | {r['class']} | {iqm} |")
    return "\n".join(lines)


def page_figure(rows: list[dict[str, Any]], path: Path, episodes: int, split: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    n = len(rows)
    if n == 0:  # every entry refused: the figure says so (the page lists why)
        fig = plt.figure(figsize=(8, 2))
        fig.text(0.5, 0.5, f"CATMiP suite {SUITE}, {split} split: no entry passed its checks", ha="center")
        return atomic_savefig(fig, path, dpi=150)
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
        (f"{r['rank']}. " if ranked and r["rank"] else "")
        + r["method"][:28]
        + (" ✓" if r["verified"] else "")
        for r in rows
    ]
    references = sum(r["class"] == "reference" for r in rows)
    if 0 < references < n:  # the reference rows (the ceiling) below a line, under the ranked ones
        for ax in (left, right):
            ax.axhline(references - 0.5, color="tab:red", lw=1.2, ls="--")
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
    verified = "; ✓ verified (replayed and fresh maps)" if any(r["verified"] for r in rows) else ""
    unranked = "" if ranked else " (not ranked: for choosing)"
    fig.suptitle(f"CATMiP suite {SUITE}, {split} split{unranked}: {episodes} maps per setting{verified}")
    fig.tight_layout()
    return atomic_savefig(fig, path, dpi=150)


def paired_names(vs: str) -> tuple[str, str]:
    """The file names of the comparison with ``vs`` (``vs_NAME.md`` and ``.csv``)."""
    stem = "vs_" + re.sub(r"[^A-Za-z0-9_.-]+", "_", vs)
    return f"{stem}.md", f"{stem}.csv"
