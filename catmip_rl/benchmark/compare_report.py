"""The report of a comparison (:func:`~catmip_rl.benchmark.compare.compare`): its rows as CSV tables,
compare.md and the figures."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from catmip_rl.store.files import atomic_write_csv, atomic_write_text

__all__ = ["Comparison"]


@dataclass
class Comparison:
    """What :func:`~catmip_rl.benchmark.compare.compare` found: rows of the paired, aggregate and
    improvement tables, plus what the plots need."""

    paired: list[dict[str, Any]] = field(default_factory=list)
    by_setting: list[dict[str, Any]] = field(default_factory=list)
    aggregate: list[dict[str, Any]] = field(default_factory=list)
    improvement: list[dict[str, Any]] = field(default_factory=list)
    scores: dict[str, np.ndarray] = field(default_factory=dict)  # method -> (runs, settings)
    settings: list[str] = field(default_factory=list)  # the columns of ``scores``
    left_out: list[str] = field(default_factory=list)  # settings not every method played alike
    curves: list[dict[str, Any]] = field(default_factory=list)  # success vs time per setting and method

    def write(self, out: str | Path) -> list[Path]:
        """compare.md, by_setting.csv, curves.csv / .png (every method's success vs time per setting, with
        95 % bands) and, where there is something to show, paired.csv / .png (two methods on the same
        maps), aggregate.csv (any method), aggregate.png, profile.png and improvement.csv (a method with
        several runs), each atomic, in ``out``; the files written."""
        from catmip_rl.evaluation.plots import plot_aggregate, plot_curves, plot_paired, plot_profiles

        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        written = []
        for name, rows in (
            ("by_setting", self.by_setting),
            ("curves", self.curves),
            ("paired", self.paired),
            ("aggregate", self.aggregate),
            ("improvement", self.improvement),
        ):
            if rows:
                written.append(atomic_write_csv(out / f"{name}.csv", rows))
        atomic_write_text(out / "compare.md", self.markdown())
        written.append(out / "compare.md")
        if self.curves:
            notes = self._unpaired_notes()
            title = "Success rate vs mission time (95 % band: bootstrap over maps and runs)"
            written.append(plot_curves(self.curves, out / "curves.png", title, notes=notes))
        if self.paired:
            written.append(plot_paired(self.paired, out / "paired.png"))
        if self.several_runs:  # with one run per method they would show single points, not spreads
            written.append(plot_aggregate(self.aggregate, out / "aggregate.png"))
            written.append(plot_profiles(self.scores, out / "profile.png"))
        return written

    def _unpaired_notes(self) -> dict[str, str]:
        """setting -> what the curves' panel says where not every method played it alike: the methods on
        other maps than the most of them, and those that did not play it."""
        notes = {}
        everyone = {r["method"] for r in self.by_setting}
        for setting in dict.fromkeys(r["setting"] for r in self.by_setting if not r["paired"]):
            rows = [r for r in self.by_setting if r["setting"] == setting]
            sets = [r["map_set"] for r in rows]
            most = max(set(sets), key=sets.count)
            other = [r["method"] for r in rows if r["map_set"] != most]
            missing = sorted(everyone - {r["method"] for r in rows})
            said = [f"{', '.join(other)} on other maps"] if other else []
            said += [f"{', '.join(missing)} not played"] if missing else []
            notes[setting] = "unpaired: " + "; ".join(said)
        return notes

    def _played_lines(self) -> list[str]:
        """What each setting was played on: one line when every method played it alike, else a line per
        set of maps with the methods that played it (the rows marked unpaired, which ``--unpaired`` let
        through: methods are paired only with those of the same maps)."""
        lines = []
        everyone = sorted({r["method"] for r in self.by_setting})
        for setting in sorted({r["setting"] for r in self.by_setting}):
            rows = [r for r in self.by_setting if r["setting"] == setting]
            if all(r["paired"] for r in rows):
                lines.append(f"- {setting}: every method played the same {_played(rows[0])}.")
                continue
            missing = sorted(set(everyone) - {r["method"] for r in rows})
            absent = f" ({', '.join(missing)} did not play it)" if missing else ""
            lines.append(f"- {setting}: **unpaired**, not every method played the same maps{absent}:")
            for k in sorted({r["map_set"] for r in rows}):
                on = [r for r in rows if r["map_set"] == k]
                lines.append(f"  - maps {k}: {_played(on[0])}: {', '.join(r['method'] for r in on)}")
        return lines

    @property
    def several_runs(self) -> bool:
        """Whether a method has several training runs: the across-run plots need a spread to show."""
        return any(r["runs"] > 1 for r in self.aggregate)

    def markdown(self) -> str:
        settings = sorted({r["setting"] for r in self.by_setting})
        lines = ["# Comparison", "", "## Success by tick 100 per setting [95 % CI]", ""]
        lines += [
            "Percentile bootstrap over the maps, and over the training runs and the maps together "
            "where a method has several runs.",
            "",
        ]
        lines += ["| method | " + " | ".join(settings) + " |", "|---|" + "---|" * len(settings)]
        cells = {}
        for r in self.by_setting:
            runs = f" ({r['runs']} runs)" if r["runs"] > 1 else ""
            mark = "" if r["paired"] else f" **unpaired** (maps {r['map_set']})"
            cells[r["method"], r["setting"]] = (
                f"{r['success_by_100']:.3f} [{r['ci_low']:.3f}, {r['ci_high']:.3f}]{runs}{mark}"
            )
        for m in sorted({r["method"] for r in self.by_setting}):
            lines.append(f"| {m} | " + " | ".join(cells.get((m, s), "–") for s in settings) + " |")
        lines += [""] + self._played_lines()
        head = "| setting | A | B | maps | success A | success B | A - B [95 % CI] | McNemar p |"
        head += " rescue tick A - B (maps) |"
        lines += ["", "## Paired per-map differences (success by tick 100, A - B)", "", head]
        lines += ["|---|---|---|---|---|---|---|---|---|"]
        for r in self.paired:
            p = "–" if r["mcnemar_p"] is None else f"{r['mcnemar_p']:.3g}"
            tick = "–"
            if r["tick_diff"] is not None:
                ci = f"[{r['tick_ci_low']:+.1f}, {r['tick_ci_high']:+.1f}]"
                tick = f"{r['tick_diff']:+.1f} {ci} ({r['both_rescued']})"
            diff = f"{r['diff']:+.3f} [{r['ci_low']:+.3f}, {r['ci_high']:+.3f}]"
            cells = [r["setting"], r["method_a"], r["method_b"], str(r["maps"]), f"{r['success_a']:.3f}"]
            cells += [f"{r['success_b']:.3f}", diff, p, tick]
            lines.append("| " + " | ".join(cells) + " |")
        if self.aggregate:
            lines += ["", f"## Across runs (training seeds): settings {', '.join(self.settings)}", ""]
            if self.left_out:
                lines += [f"Left out (not played alike by every method): {', '.join(self.left_out)}.", ""]
            lines += ["| method | runs | IQM [95 % CI] | mean [95 % CI] |", "|---|---|---|---|"]
            for r in self.aggregate:
                iqm, mean = (_interval(r, k) for k in ("iqm", "mean"))
                lines.append(f"| {r['method']} | {r['runs']} | {iqm} | {mean} |")
            lines += [
                "",
                "(one run: no interval across seeds; its uncertainty over maps is in the paired table)",
            ]
            if not self.several_runs:
                lines += [
                    "",
                    "No aggregate.png or profile.png: every method has one run, so they "
                    "would show single points (training seeds: NAME=DIR,DIR,...).",
                ]
        if self.improvement:
            lines += ["", "| P(X > Y) | X | Y | 95 % CI |", "|---|---|---|---|"]
            for r in self.improvement:
                ci = f"[{r['ci_low']:.3f}, {r['ci_high']:.3f}]"
                lines.append(f"| {r['probability']:.3f} | {r['method_x']} | {r['method_y']} | {ci} |")
        return "\n".join(lines) + "\n"


def _played(row: dict[str, Any]) -> str:
    horizon = "" if row["horizon"] is None else f", horizon {row['horizon']}"
    return f"{row['maps']} maps of seed {row['seed']}{horizon} (sha256 {row['maps_sha256'][:12]})"


def _interval(row: dict[str, Any], key: str) -> str:
    if row[f"{key}_ci_low"] is None:
        return f"{row[key]:.3f}"
    return f"{row[key]:.3f} [{row[f'{key}_ci_low']:.3f}, {row[f'{key}_ci_high']:.3f}]"
