"""The fresh-map rule: does a training run play, on maps drawn at verification time, what its entry claims?

A run's claim in a setting is its success by tick 100 on the entry's ``N`` maps (1,000 for a full entry);
the check plays ``M`` fresh maps of every setting (:data:`FRESH_MAPS`), maps nobody could have played
before, and compares. The gap ``claimed - played`` is measured in standard errors of a difference of two
proportions (:func:`gap_z`: the pooled rate, ``1/M + 1/N``, so that the claim's own sampling noise
counts). A run is refused when

* **a setting** falls short: its gap on the first ``M`` maps exceeds :data:`Z_SUSPECT`, the check then
  plays :data:`SECOND_STAGE` × ``M`` more fresh maps of that setting, and the gap on all of them exceeds
  :data:`Z_SETTING`; or
* **the settings pooled** fall short: the mean gap over the settings (first ``M`` maps each) exceeds
  :data:`Z_POOLED` standard errors.

An entry is refused when one of its runs is. The thresholds were chosen for ``M = 50``
(:func:`calibrate` measures them on the committed entries, docs/verification.md): an honest entry is
refused with probability under 0.01, and a run that claims 0.25 more than it plays in one setting, or
0.10 more pooled over the settings, is refused with probability at least 0.95.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "FRESH_MAPS",
    "SECOND_STAGE",
    "Z_SUSPECT",
    "Z_SETTING",
    "Z_POOLED",
    "gap_z",
    "suspicious",
    "judge_run",
    "RunVerdict",
    "calibrate",
]

FRESH_MAPS = 50  # M: fresh maps a setting (catmip leaderboard --fresh M)
SECOND_STAGE = 3  # a suspicious setting plays SECOND_STAGE x M more fresh maps
Z_SUSPECT = 1.3  # a setting's gap (in standard errors) past which it plays the second stage
Z_SETTING = 3.8  # ... and past which, on all its fresh maps, the run is refused
Z_POOLED = 3.3  # the mean gap over the settings past which the run is refused


def _se(claimed: float, n: int, played: float, m: int) -> float:
    pooled = (claimed * n + played * m) / (n + m)
    return math.sqrt(max(pooled * (1 - pooled), 1e-12) * (1 / m + 1 / n))


def gap_z(claimed: float, n: int, successes: int, m: int) -> float:
    """The gap ``claimed - successes/m`` in standard errors of a difference of two proportions (the
    claim's ``n`` maps and the ``m`` fresh ones, their pooled rate): positive where the run plays below
    its claim."""
    played = successes / m
    return (claimed - played) / _se(claimed, n, played, m)


def suspicious(claimed: dict[str, float], n: int, first: dict[str, int], m: int) -> list[str]:
    """The settings whose gap on the first ``m`` fresh maps (``first``: successes by setting) exceeds
    :data:`Z_SUSPECT`: those that play the second stage."""
    return [label for label in claimed if gap_z(claimed[label], n, first[label], m) > Z_SUSPECT]


@dataclass
class RunVerdict:
    """What the rule found for one run: ``refused`` and why (one line), the pooled gap and its z, and
    per setting the rate claimed, the rate played on the fresh maps (all of them), their count and z."""

    refused: bool
    reason: str = ""
    pooled: dict[str, float] = field(default_factory=dict)
    settings: dict[str, dict[str, Any]] = field(default_factory=dict)


def judge_run(
    claimed: dict[str, float],
    n: int,
    first: dict[str, int],
    m: int,
    second: dict[str, tuple[int, int]] | None = None,
) -> RunVerdict:
    """The rule on one run: ``claimed`` success by tick 100 per setting (on the entry's ``n`` maps),
    ``first``: successes on the first ``m`` fresh maps of each setting, ``second``: (successes, maps) of
    the second stage of the settings that played one (:func:`suspicious`)."""
    second = second or {}
    settings, worst = {}, None
    for label, c in claimed.items():
        k, maps = first[label], m
        if label in second:
            k, maps = k + second[label][0], m + second[label][1]
        z = gap_z(c, n, k, maps)
        settings[label] = {"claimed": c, "played": k / maps, "maps": maps, "z": z}
        if label in second and z > Z_SETTING and (worst is None or z > settings[worst]["z"]):
            worst = label
    played = {label: first[label] / m for label in claimed}
    se = math.sqrt(sum(_se(claimed[lb], n, played[lb], m) ** 2 for lb in claimed)) / len(claimed)
    pooled = {
        "claimed": float(np.mean(list(claimed.values()))),
        "played": float(np.mean(list(played.values()))),
    }
    pooled["gap"] = pooled["claimed"] - pooled["played"]
    pooled["z"] = pooled["gap"] / se
    if worst is not None:
        s = settings[worst]
        why = (
            f"{worst}: claims {s['claimed']:.3f} by tick 100, plays {s['played']:.3f} on {s['maps']} fresh "
            f"maps (z = {s['z']:.1f} > {Z_SETTING})"
        )
        return RunVerdict(True, why, pooled, settings)
    if pooled["z"] > Z_POOLED:
        why = (
            f"pooled over the settings: claims {pooled['claimed']:.3f} by tick 100, plays "
            f"{pooled['played']:.3f} on {m} fresh maps a setting (z = {pooled['z']:.1f} > {Z_POOLED})"
        )
        return RunVerdict(True, why, pooled, settings)
    return RunVerdict(False, "", pooled, settings)


def _judge_draw(claimed: dict[str, float], n: int, m: int, draw) -> bool:
    first = dict(zip(claimed, draw(m)))
    late = suspicious(claimed, n, first, m)
    second = None
    if late:
        extra = dict(zip(claimed, draw(SECOND_STAGE * m)))
        second = {label: (int(extra[label]), SECOND_STAGE * m) for label in late}
    return judge_run(claimed, n, first, m, second).refused


def calibrate(
    entries: list[dict[str, Any]], m: int = FRESH_MAPS, draws: int = 2_000, seed: int = 0
) -> dict[str, Any]:
    """The rule measured on checked ``entries`` (:func:`~catmip_rl.benchmark.entry_check.load_entries`):

    * ``false_refusal``: per entry, the share of ``draws`` honest checks that refuse it, two ways: each
      setting's ``m`` fresh maps resampled from the run's own recorded successes (``resampled``), and
      drawn at a rate from the posterior of its claim (``posterior``: the claim's own noise too);
    * ``power``: per run, the share of checks that refuse it when it plays 0.25 below its claim in one
      setting (the setting whose shifted rate is nearest 0.5, where the test is weakest; settings
      claiming under 0.25 cannot be shifted) and when it plays 0.10 below pooled (spread evenly over
      the settings as far as their claims allow).
    """
    rng = np.random.default_rng(seed)
    false_refusal: dict[str, dict[str, float]] = {}
    power_one, power_pooled = [], []
    for e in entries:
        success = e["checked"]["success"]  # label -> (runs, maps) bool
        labels = list(success)
        n = success[labels[0]].shape[1]
        counts = {"resampled": 0, "posterior": 0}
        for _ in range(draws):
            hit = {"resampled": False, "posterior": False}
            for k in range(success[labels[0]].shape[0]):
                rows = np.stack([success[lb][k] for lb in labels])  # (settings, maps)
                claimed = dict(zip(labels, rows.mean(axis=1).tolist()))
                hits = rows.sum(axis=1)

                def resampled(size, rows=rows, n=n):
                    return rows[np.arange(len(rows))[:, None], rng.integers(n, size=(len(rows), size))].sum(1)

                rates = rng.beta(hits + 0.5, n - hits + 0.5)
                hit["resampled"] |= _judge_draw(claimed, n, m, resampled)
                hit["posterior"] |= _judge_draw(claimed, n, m, lambda size, p=rates: rng.binomial(size, p))
            for key in counts:
                counts[key] += hit[key]
        false_refusal[e["method"]] = {key: value / draws for key, value in counts.items()}
        for k in range(success[labels[0]].shape[0]):
            claimed = {lb: float(success[lb][k].mean()) for lb in labels}
            rates = np.array([claimed[lb] for lb in labels])
            able = [j for j, c in enumerate(rates) if c >= 0.25]
            if able:
                j = min(able, key=lambda j: abs(rates[j] - 0.75))
                shifted = rates.copy()
                shifted[j] -= 0.25
                power_one.append(_power(claimed, n, m, shifted, draws, rng))
            cut = _spread(rates, 0.10 * len(rates))
            if cut is not None:
                power_pooled.append(_power(claimed, n, m, rates - cut, draws, rng))
    return {
        "fresh_maps": m,
        "draws": draws,
        "false_refusal": false_refusal,
        "power_one_setting_0.25": {"min": min(power_one), "mean": float(np.mean(power_one))},
        "power_pooled_0.10": {"min": min(power_pooled), "mean": float(np.mean(power_pooled))},
        "runs": len(power_one),
    }


def _power(claimed, n, m, rates, draws, rng) -> float:
    return (
        sum(_judge_draw(claimed, n, m, lambda size: rng.binomial(size, rates)) for _ in range(draws)) / draws
    )


def _spread(rates: np.ndarray, total: float) -> np.ndarray | None:
    """A cut of ``total`` over the settings, even where the rates allow it, the rest on the highest
    rates; None if the rates sum to less."""
    if rates.sum() < total:
        return None
    cut = np.minimum(rates, total / len(rates))
    for j in np.argsort(-rates):
        more = min(rates[j] - cut[j], total - cut.sum())
        cut[j] += max(more, 0.0)
    return cut
