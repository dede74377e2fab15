"""The statistics of evaluation results: bootstrap intervals over maps (and training runs), paired
differences, McNemar's test and the band of a success-vs-time curve. ``catmip compare``, ``catmip bench
paper``, the suite and the leaderboard use them."""

from __future__ import annotations

import numpy as np

__all__ = [
    "CONFIDENCE",
    "paired_difference",
    "mcnemar_p",
    "runs_and_maps_ci",
    "shared_maps_cis",
    "success_interval",
    "curve_band",
]

CONFIDENCE = 0.95
RESAMPLES = 10_000  # paired bootstrap over maps (scipy: vectorised, ~0.2 s a pair)
CURVE_RESAMPLES = 1_000


def _bootstrap_ci(data: np.ndarray, seed: int = 0) -> tuple[float, float]:
    """95 % percentile bootstrap CI of the mean of ``data`` (one value per map)."""
    from scipy.stats import bootstrap

    if len(data) < 2 or np.all(data == data[0]):
        return float(data.mean()), float(data.mean())
    res = bootstrap(
        (data,),
        np.mean,
        confidence_level=CONFIDENCE,
        n_resamples=RESAMPLES,
        method="percentile",
        rng=np.random.default_rng(seed),
    )
    return float(res.confidence_interval.low), float(res.confidence_interval.high)


def paired_difference(a: np.ndarray, b: np.ndarray, seed: int = 0) -> dict[str, float]:
    """Mean of ``a - b`` over paired maps with its 95 % bootstrap CI (``a``, ``b``: (E,) per-map
    scores, the same maps in the same order)."""
    d = np.asarray(a, float) - np.asarray(b, float)
    low, high = _bootstrap_ci(d, seed)
    return {"diff": float(d.mean()), "ci_low": low, "ci_high": high}


def mcnemar_p(a: np.ndarray, b: np.ndarray) -> float:
    """Exact McNemar p-value (two-sided binomial test on the maps where exactly one succeeded)."""
    from scipy.stats import binomtest

    only_a, only_b = int(np.sum(a & ~b)), int(np.sum(~a & b))
    return 1.0 if only_a + only_b == 0 else float(binomtest(only_a, only_a + only_b, 0.5).pvalue)


def runs_and_maps_ci(success: np.ndarray, seed: int = 0) -> tuple[float, float]:
    """95 % percentile CI of the mean of ``success`` (runs, maps) when both the training runs and the
    maps are a sample: each resample draws runs with replacement and, for all of them alike, maps with
    replacement (the runs played the same maps). Neither scipy's bootstrap nor rliable's (over runs
    only) resamples the two levels together; with three runs, resampling the runs alone would hide the
    maps' share of the uncertainty."""
    rng = np.random.default_rng(seed)
    r, e = success.shape
    means = np.empty(RESAMPLES)
    for k in range(0, RESAMPLES, 500):  # 500 resamples at a time: (500, r, e) stays small
        n = min(500, RESAMPLES - k)
        runs = rng.integers(r, size=(n, r))
        maps = rng.integers(e, size=(n, e))
        means[k : k + n] = success[runs[:, :, None], maps[:, None, :]].mean(axis=(1, 2))
    low, high = np.quantile(means, [(1 - CONFIDENCE) / 2, (1 + CONFIDENCE) / 2])
    return float(low), float(high)


def shared_maps_cis(arrays: list[np.ndarray], seed: int = 0) -> list[tuple[float, float]]:
    """:func:`runs_and_maps_ci` of every (runs, maps) array of ``arrays``, all over the same maps, from one
    set of map resamples shared by all: each resample is a row of counts per map, so every run's
    resampled mean is one matrix product instead of a gather (a leaderboard's 150 intervals in about a
    second rather than 20)."""
    rng = np.random.default_rng(seed)
    e = arrays[0].shape[1]
    drawn = rng.integers(e, size=(RESAMPLES, e)) + e * np.arange(RESAMPLES)[:, None]
    counts = np.bincount(drawn.ravel(), minlength=RESAMPLES * e).reshape(RESAMPLES, e).astype(np.float32)
    intervals = []
    for a in arrays:
        a = np.asarray(a, np.float32)
        per_run = counts @ a.T / e  # (resamples, runs): each run's mean over the resampled maps
        runs = rng.integers(a.shape[0], size=(RESAMPLES, a.shape[0]))
        means = np.take_along_axis(per_run, runs, axis=1).mean(axis=1)
        low, high = np.quantile(means, [(1 - CONFIDENCE) / 2, (1 + CONFIDENCE) / 2])
        intervals.append((float(low), float(high)))
    return intervals


def success_interval(success: np.ndarray, seed: int = 0) -> tuple[float, float, str]:
    """95 % CI of the mean of ``success`` (runs, maps; the runs played the same maps) and what it is
    over: the maps for one run (percentile bootstrap), the runs and the maps together for several
    (:func:`runs_and_maps_ci`)."""
    success = np.asarray(success, float)
    if success.shape[0] > 1:
        return (*runs_and_maps_ci(success, seed), "runs and maps")
    return (*_bootstrap_ci(success[0], seed), "maps")


def curve_band(rescue_tick: np.ndarray, horizon: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """95 % percentile band of a success-vs-time curve (rescued by tick t, t = 0 .. horizon) from its
    rescue ticks ((runs, maps), NaN or -1: not rescued): each resample draws the runs and, for all of
    them alike, the maps with replacement (the runs played the same maps), as :func:`runs_and_maps_ci`."""
    ticks = np.asarray(rescue_tick, float)
    ticks = np.where(np.isnan(ticks) | (ticks < 0), np.inf, ticks)
    rng = np.random.default_rng(seed)
    r, e = ticks.shape
    grid = np.arange(horizon + 1)
    curves = np.empty((CURVE_RESAMPLES, horizon + 1))
    for k in range(CURVE_RESAMPLES):
        sample = np.sort(ticks[rng.integers(r, size=r)][:, rng.integers(e, size=e)].ravel())
        curves[k] = np.searchsorted(sample, grid, side="right") / sample.size
    low, high = np.quantile(curves, [(1 - CONFIDENCE) / 2, (1 + CONFIDENCE) / 2], axis=0)
    return low, high
