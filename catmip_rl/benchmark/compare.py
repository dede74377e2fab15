"""Statistics over evaluation results: paired per-map differences and aggregates across training seeds.

    results = load_results(["out/eval", "mappo=out/mappo-s0,out/mappo-s1,out/mappo-s2"])  # .results
    report = compare(results)            # paired differences, IQM / mean with CIs, P(improvement)
    report.write("out/compare")          # paired.csv, aggregate.csv, improvement.csv, *.png, compare.md

A *result* is a folder ``catmip eval`` wrote (``summary.json`` + ``episodes.json``); folders are searched
recursively, so a ``catmip bench paper`` figure folder gives all its runs. Results of one method are
grouped by its name (``NAME=DIR[,DIR...]`` renames every result found under those folders: the
training seeds of one algorithm). The score of an episode is "rescued by tick 100" (or by the horizon
if shorter), the paper's headline measure. What is read is checked first
(:mod:`~catmip_rl.benchmark.results_check`: one line naming the folder for an empty, inconsistent or
duplicated result, or a copied folder given as a second run of its method).

Every method must have played what every other played (:func:`played_on`: the setting, the map seed,
the horizon and the maps themselves, by the digest of their map hashes), and the runs of one method the
same in each setting: otherwise :func:`check_alike` refuses in one line naming two folders and what
differs (a method evaluated on another ``--seed``, setting or episode count). ``unpaired=True``
(``catmip compare --unpaired``) shows such methods side by side instead, each row marked paired or
unpaired; the runs of one method must still agree.

* **Paired comparisons** (every pair of methods, in every setting where both played the same maps, map
  hash by map hash): the mean per-map difference in success by tick 100 with a 95 % percentile
  bootstrap CI over maps (``scipy.stats.bootstrap``, paired), an exact McNemar p-value (binomial test
  on the discordant maps) when each method has one run, and the difference in mean rescue tick over
  the maps both rescued, with its paired CI. A method with several runs enters with its per-map mean.
* **Across training seeds** (rliable, Agarwal et al. 2021): for each method the interquartile mean and
  the mean of the (runs x settings) success-by-100 scores with 95 % stratified-bootstrap CIs, the
  probability of improvement of every method over every other, and performance profiles. Settings
  that not every method played are left out of these (and named).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from itertools import combinations
from pathlib import Path
from typing import Any

import numpy as np

from catmip_rl.benchmark.results import Result, check_alike, played_on
from catmip_rl.benchmark.results_check import (
    check_runs,
)
from catmip_rl.evaluation.stats import CONFIDENCE, curve_band, mcnemar_p, paired_difference, success_interval
from catmip_rl.store.files import atomic_write_csv, atomic_write_text

__all__ = ["compare", "Comparison"]

RLIABLE_RESAMPLES = 2_000  # rliable's stratified bootstrap runs a Python call per resample (~1 ms)


@dataclass
class Comparison:
    """What :func:`compare` found: rows of the paired, aggregate and improvement tables, plus what the
    plots need."""

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
        lines += ["Percentile bootstrap over the maps, and over the training runs and the maps together "
                  "where a method has several runs.", ""]  # fmt: skip
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
                lines += ["", "No aggregate.png or profile.png: every method has one run, so they "
                          "would show single points (training seeds: NAME=DIR,DIR,...)."]  # fmt: skip
        if self.improvement:
            lines += ["", "| P(X > Y) | X | Y | 95 % CI |", "|---|---|---|---|"]
            for r in self.improvement:
                ci = f"[{r['ci_low']:.3f}, {r['ci_high']:.3f}]"
                lines.append(f"| {r['probability']:.3f} | {r['method_x']} | {r['method_y']} | {ci} |")
        return "\n".join(lines) + "\n"


def _setting_rows(groups: dict[str, dict[str, list[Result]]], seed: int) -> list[dict[str, Any]]:
    """Per setting and method: success by tick 100 (the mean over runs) with a 95 % CI: over the maps
    for one run (scipy's percentile bootstrap), over runs and maps together for several runs of the
    same maps (:func:`runs_and_maps_ci`); the success by the horizon and the mean rescue tick beside it."""

    everyone = {m for per in groups.values() for m in per}
    rows = []
    for setting, methods in sorted(groups.items()):
        played = {m: played_on(runs[0]) for m, runs in sorted(methods.items())}  # check_alike: runs alike
        groups_of_maps = list(dict.fromkeys(played.values()))  # the map sets played, numbered from 1
        for method, runs in sorted(methods.items()):
            success = np.array([r.success for r in runs], float)  # (runs, maps)
            mean = float(success.mean())
            low, high, over = success_interval(success, seed)
            ticks = [np.nanmean(r.rescue_tick) for r in runs if not np.all(np.isnan(r.rescue_tick))]
            rows.append({
                "setting": setting, "method": method, "runs": len(runs), "maps": len(runs[0].maps),
                "success_by_100": mean, "ci_low": low, "ci_high": high, "ci_over": over,
                "success": float(np.mean([(~np.isnan(r.rescue_tick)).mean() for r in runs])),
                "mean_rescue_tick": float(np.mean(ticks)) if ticks else None,
                "seed": played[method].seed, "horizon": played[method].horizon,
                "maps_sha256": played[method].maps_sha256,
                "paired": set(methods) == everyone and len(groups_of_maps) == 1,
                "map_set": groups_of_maps.index(played[method]) + 1,
            })  # fmt: skip
    return rows


def _played(row: dict[str, Any]) -> str:
    horizon = "" if row["horizon"] is None else f", horizon {row['horizon']}"
    return f"{row['maps']} maps of seed {row['seed']}{horizon} (sha256 {row['maps_sha256'][:12]})"


def _curve_rows(groups: dict[str, dict[str, list[Result]]], seed: int) -> list[dict[str, Any]]:
    """Per setting and method the success rate by each tick (the mean over its runs) with its 95 %
    percentile band (:func:`~catmip_rl.evaluation.stats.curve_band`: a bootstrap over the maps, and the
    runs with them), as rows for :func:`~catmip_rl.evaluation.plots.plot_curves`."""
    rows = []
    for setting, methods in sorted(groups.items()):
        for method, runs in sorted(methods.items()):
            ticks = np.array([r.rescue_tick for r in runs], float)  # (runs, maps), nan: not rescued
            finite = ticks[~np.isnan(ticks)]
            horizon = runs[0].horizon or int(max(100, finite.max() if finite.size else 0))
            grid = np.arange(horizon + 1)
            with np.errstate(invalid="ignore"):  # nan <= t is False: not rescued
                curve = (ticks[:, :, None] <= grid).mean(axis=(0, 1))
            low, high = curve_band(ticks, horizon, seed)
            at = {"panel": setting, "method": method, "runs": len(runs)}
            rows += [at | {"tick": int(t), "success_rate": float(curve[t]), "ci_low": float(low[t]),
                           "ci_high": float(high[t])} for t in grid]  # fmt: skip
    return rows


def _interval(row: dict[str, Any], key: str) -> str:
    if row[f"{key}_ci_low"] is None:
        return f"{row[key]:.3f}"
    return f"{row[key]:.3f} [{row[f'{key}_ci_low']:.3f}, {row[f'{key}_ci_high']:.3f}]"


def _by_setting(results: list[Result]) -> dict[str, dict[str, list[Result]]]:
    out: dict[str, dict[str, list[Result]]] = {}
    for r in results:
        out.setdefault(r.setting, {}).setdefault(r.method, []).append(r)
    return out


def _ordered_pairs(
    methods: list[str], vs: str | None, pairs: list[tuple[str, str]] | None
) -> list[tuple[str, str]]:
    """The (A, B) pairs to compare among ``methods``: every pair, each method against ``vs`` (A - vs), or
    the chosen ``pairs`` (those both of whose methods are there)."""
    if vs is not None:
        return [(m, vs) for m in methods if m != vs] if vs in methods else []
    if pairs is not None:
        return [(a, b) for a, b in pairs if a in methods and b in methods]
    return list(combinations(methods, 2))


def _paired_rows(groups: dict[str, dict[str, list[Result]]], vs: str | None = None,
                 pairs: list[tuple[str, str]] | None = None) -> list[dict[str, Any]]:  # fmt: skip
    rows = []
    for setting, methods in sorted(groups.items()):
        for ma, mb in _ordered_pairs(sorted(methods), vs, pairs):
            ra, rb = methods[ma], methods[mb]
            maps = ra[0].maps
            if any(r.maps != maps for r in (*ra, *rb)):
                continue  # not the same maps: no paired comparison
            sa = np.mean([r.success for r in ra], axis=0)  # (E,) per-map mean over runs
            sb = np.mean([r.success for r in rb], axis=0)
            row = {"setting": setting, "method_a": ma, "method_b": mb, "maps": len(maps), "runs_a": len(ra),
                   "runs_b": len(rb), "success_a": float(sa.mean()),
                   "success_b": float(sb.mean())}  # fmt: skip
            row |= paired_difference(sa, sb)
            single = len(ra) == len(rb) == 1
            row["mcnemar_p"] = mcnemar_p(ra[0].success, rb[0].success) if single else None
            # rescue ticks are paired for one run each (a per-map mean over runs would mix rescued and
            # unrescued runs): over the maps both rescued
            ta, tb = ra[0].rescue_tick, rb[0].rescue_tick
            both = ~np.isnan(ta) & ~np.isnan(tb)
            row |= {"both_rescued": int(both.sum()) if single else None, "tick_diff": None,
                    "tick_ci_low": None, "tick_ci_high": None}  # fmt: skip
            if single and both.sum() >= 2:
                t = paired_difference(ta[both], tb[both])
                row |= {"tick_diff": t["diff"], "tick_ci_low": t["ci_low"], "tick_ci_high": t["ci_high"]}
            rows.append(row)
    return rows


def _score_matrices(
    groups: dict[str, dict[str, list[Result]]],
) -> tuple[dict[str, np.ndarray], list[str], list[str]]:
    """method -> (runs, settings) success-by-100 over the settings every method played alike (the same
    maps: :func:`played_on`), the settings, and those left out. A method's runs are its results in each
    setting, in folder order; a method with different run counts across settings keeps the smallest
    count."""
    methods = sorted({m for per in groups.values() for m in per})
    common = sorted(
        s for s, per in groups.items()
        if all(m in per for m in methods) and len({played_on(runs[0]) for runs in per.values()}) == 1
    )  # fmt: skip
    left_out = sorted(set(groups) - set(common))
    scores = {}
    for m in methods:
        runs = min((len(groups[s][m]) for s in common), default=0)
        if runs:
            scores[m] = np.array([[groups[s][m][k].success.mean() for s in common] for k in range(runs)])
    return scores, common, left_out


def compare(
    results: list[Result],
    seed: int = 0,
    vs: str | None = None,
    pairs: list[tuple[str, str]] | None = None,
    unpaired: bool = False,
) -> Comparison:
    """Paired differences on the same maps (every pair of methods; each against ``vs``, as method - vs; or
    the chosen ``pairs`` (A, B), as A - B), and (with rliable) IQM / mean with 95 % stratified-bootstrap
    CIs and the probability of improvement across runs and settings. Every method must have played
    alike (:func:`check_alike`); with ``unpaired`` they may not have, and the rows say which are."""
    if not results:
        raise ValueError("nothing to compare: no results")
    check_runs(results)
    check_alike(results, unpaired)
    names = sorted({r.method for r in results})
    for wanted in ([vs] if vs is not None else []) + [m for pair in pairs or [] for m in pair]:
        if wanted not in names:
            raise ValueError(f"no results of method {wanted!r} to compare against; the methods are {names}")
    groups = _by_setting(results)
    report = Comparison(paired=_paired_rows(groups, vs, pairs), by_setting=_setting_rows(groups, seed),
                        curves=_curve_rows(groups, seed))  # fmt: skip
    scores, report.settings, report.left_out = _score_matrices(groups)
    report.scores = scores
    if len(scores) < 1 or not report.settings:
        return report
    try:
        from rliable import library as rly
        from rliable import metrics
    except ImportError as err:
        raise ImportError(
            f"catmip compare needs the stats extra ({err}): pip install 'catmip[stats]'"
        ) from None

    def both(x: np.ndarray) -> np.ndarray:
        return np.array([metrics.aggregate_iqm(x), metrics.aggregate_mean(x)])

    # one run has no spread across seeds to resample: its row has point estimates only (its map-level
    # uncertainty is in the paired table), and a pair needs a method with runs to resample
    multi = {m: x for m, x in scores.items() if x.shape[0] >= 2}
    ci: dict[str, np.ndarray] = {}
    if multi:
        with warnings.catch_warnings():  # arch (under rliable) deprecates the RandomState rliable passes
            warnings.simplefilter("ignore", FutureWarning)
            _, ci = rly.get_interval_estimates(
                multi, both, reps=RLIABLE_RESAMPLES, confidence_interval_size=CONFIDENCE,
                random_state=np.random.RandomState(seed),
            )  # fmt: skip
    for m in sorted(scores):
        iqm, mean = both(scores[m])
        row = {"method": m, "runs": scores[m].shape[0], "settings": len(report.settings), "iqm": float(iqm)}
        c = ci.get(m)
        row |= {
            "iqm_ci_low": None if c is None else float(c[0, 0]),
            "iqm_ci_high": None if c is None else float(c[1, 0]),
        }
        row |= {"mean": float(mean), "mean_ci_low": None if c is None else float(c[0, 1])}
        row["mean_ci_high"] = None if c is None else float(c[1, 1])
        report.aggregate.append(row)
    # P(X > Y) for each unordered pair (P(Y > X) = 1 - P(X > Y): ties count one half)
    pairs = {
        f"{x}\t{y}": (scores[x], scores[y])
        for x, y in combinations(sorted(scores), 2)
        if x in multi or y in multi
    }
    if pairs:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            poi, poi_ci = rly.get_interval_estimates(
                pairs, metrics.probability_of_improvement, reps=RLIABLE_RESAMPLES,
                confidence_interval_size=CONFIDENCE, random_state=np.random.RandomState(seed),
            )  # fmt: skip
        for key in pairs:
            x, y = key.split("\t")
            low, high = np.ravel(poi_ci[key])
            report.improvement.append({"method_x": x, "method_y": y, "probability": float(poi[key]),
                                       "ci_low": float(low), "ci_high": float(high)})  # fmt: skip
    return report
