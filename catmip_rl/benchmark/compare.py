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

The report, its tables, compare.md and figures: :class:`~catmip_rl.benchmark.compare_report.Comparison`.
"""

from __future__ import annotations

import warnings
from itertools import combinations
from typing import Any

import numpy as np

from catmip_rl.benchmark.compare_report import Comparison
from catmip_rl.benchmark.results import Result, check_alike, played_on
from catmip_rl.benchmark.results_check import check_runs
from catmip_rl.evaluation.stats import CONFIDENCE, curve_band, mcnemar_p, paired_difference, success_interval

__all__ = ["compare"]

RLIABLE_RESAMPLES = 2_000  # rliable's stratified bootstrap runs a Python call per resample (~1 ms)


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
            rows.append(
                {
                    "setting": setting,
                    "method": method,
                    "runs": len(runs),
                    "maps": len(runs[0].maps),
                    "success_by_100": mean,
                    "ci_low": low,
                    "ci_high": high,
                    "ci_over": over,
                    "success": float(np.mean([(~np.isnan(r.rescue_tick)).mean() for r in runs])),
                    "mean_rescue_tick": float(np.mean(ticks)) if ticks else None,
                    "seed": played[method].seed,
                    "horizon": played[method].horizon,
                    "maps_sha256": played[method].maps_sha256,
                    "paired": set(methods) == everyone and len(groups_of_maps) == 1,
                    "map_set": groups_of_maps.index(played[method]) + 1,
                }
            )
    return rows


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
            for t in grid:
                band = {"ci_low": float(low[t]), "ci_high": float(high[t])}
                rows.append(at | {"tick": int(t), "success_rate": float(curve[t])} | band)
    return rows


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


def _paired_rows(
    groups: dict[str, dict[str, list[Result]]],
    vs: str | None = None,
    pairs: list[tuple[str, str]] | None = None,
) -> list[dict[str, Any]]:
    rows = []
    for setting, methods in sorted(groups.items()):
        for ma, mb in _ordered_pairs(sorted(methods), vs, pairs):
            ra, rb = methods[ma], methods[mb]
            maps = ra[0].maps
            if any(r.maps != maps for r in (*ra, *rb)):
                continue  # not the same maps: no paired comparison
            sa = np.mean([r.success for r in ra], axis=0)  # (E,) per-map mean over runs
            sb = np.mean([r.success for r in rb], axis=0)
            row = {
                "setting": setting,
                "method_a": ma,
                "method_b": mb,
                "maps": len(maps),
                "runs_a": len(ra),
                "runs_b": len(rb),
                "success_a": float(sa.mean()),
                "success_b": float(sb.mean()),
            }
            row |= paired_difference(sa, sb)
            single = len(ra) == len(rb) == 1
            row["mcnemar_p"] = mcnemar_p(ra[0].success, rb[0].success) if single else None
            # rescue ticks are paired for one run each (a per-map mean over runs would mix rescued and
            # unrescued runs): over the maps both rescued
            ta, tb = ra[0].rescue_tick, rb[0].rescue_tick
            both = ~np.isnan(ta) & ~np.isnan(tb)
            row |= {
                "both_rescued": int(both.sum()) if single else None,
                "tick_diff": None,
                "tick_ci_low": None,
                "tick_ci_high": None,
            }
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
        s
        for s, per in groups.items()
        if all(m in per for m in methods) and len({played_on(runs[0]) for runs in per.values()}) == 1
    )
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
    report = Comparison(
        paired=_paired_rows(groups, vs, pairs),
        by_setting=_setting_rows(groups, seed),
        curves=_curve_rows(groups, seed),
    )
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
                multi,
                both,
                reps=RLIABLE_RESAMPLES,
                confidence_interval_size=CONFIDENCE,
                random_state=np.random.RandomState(seed),
            )
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
                pairs,
                metrics.probability_of_improvement,
                reps=RLIABLE_RESAMPLES,
                confidence_interval_size=CONFIDENCE,
                random_state=np.random.RandomState(seed),
            )
        for key in pairs:
            x, y = key.split("\t")
            low, high = np.ravel(poi_ci[key])
            report.improvement.append(
                {
                    "method_x": x,
                    "method_y": y,
                    "probability": float(poi[key]),
                    "ci_low": float(low),
                    "ci_high": float(high),
                }
            )
    return report
