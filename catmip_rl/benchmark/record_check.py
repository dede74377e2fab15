"""What a verification record must hold (:mod:`~catmip_rl.benchmark.verify`'s ``verification.json``)
before a page renders from it: its fields, and for every entry it says was verified, the maps its seed
draws and numbers by which the fresh-map rule refuses nothing. A record written by hand to pass an entry
must at least hold together; only playing again (``--replay``, CI's repeat of a random entry) shows
whether its fresh numbers are what the maps give."""

from __future__ import annotations

from typing import Any

import numpy as np

from catmip_rl.benchmark import fresh_rule
from catmip_rl.benchmark.entry import SETTINGS, rescued_by_100
from catmip_rl.benchmark.replay import replay_indices

__all__ = ["check_record"]


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value)


def check_record(record: Any, entries: list[dict[str, Any]]) -> None:
    """ValueError naming the first thing by which ``record`` is not what a check of ``entries`` writes:
    its fields and their types; for each entry it says was verified, every run's replayed maps are the
    ones its seed draws (:func:`~catmip_rl.benchmark.replay.replay_indices`), its claims are the
    entry's, its fresh maps number the record's M (or its second stage), and the rule, applied to the
    numbers it states, refuses none. A record written by hand to pass an entry must also hold together."""
    if not isinstance(record, dict) or not isinstance(record.get("entries"), dict):
        raise ValueError("it has no entries object")
    seed, replay, fresh = record.get("seed"), record.get("replay"), record.get("fresh")
    if type(seed) is not int or not (replay == "all" or type(replay) is int) or type(fresh) is not int:
        raise ValueError("its seed, replay and fresh must be integers (replay may be 'all')")
    for key in ("created", "versions", "machine"):
        if not isinstance(record.get(key), (str, dict)):
            raise ValueError(f"it has no {key}")
    by_name = {e["method"]: e for e in entries}
    for method, said in record["entries"].items():
        if not isinstance(said, dict) or said.get("outcome") not in (
            "verified",
            "refused",
            "cannot verify here",
        ):
            raise ValueError(f"{method}: no outcome")
        for key in ("reason", "sha256", "class", "class_note"):
            if not isinstance(said.get(key), str):
                raise ValueError(f"{method}: its {key} is not a string")
        entry = by_name.get(method)
        if said["outcome"] == "verified" and entry is not None:
            _check_verified(method, said, entry, seed, None if replay == "all" else replay, fresh)


def _check_verified(method: str, said: dict, entry: dict, seed: int, replay: int | None, fresh: int) -> None:
    runs = said.get("runs")
    if not isinstance(runs, list) or len(runs) != len(entry["runs"]):
        raise ValueError(f"{method}: it states other runs than the entry's {len(entry['runs'])}")
    for k, run in enumerate(runs):
        n = entry["episodes"]
        if not isinstance(run, dict) or "error" in run:
            raise ValueError(f"{method}: run {k} is verified with an error")
        if replay != 0:
            for st in SETTINGS:
                picks = replay_indices(seed, method, k, st.label, n, replay)
                if (run.get("replayed") or {}).get(st.label) != picks:
                    raise ValueError(
                        f"{method}: run {k}'s replayed maps of {st.label} are not the ones its seed draws"
                    )
        if fresh:
            _check_fresh(method, k, run, entry, fresh)


def _check_fresh(method: str, k: int, run: dict, entry: dict, fresh: int) -> None:
    """ValueError unless run ``k``'s fresh numbers are its claims on ``fresh`` maps (or the second stage's)
    and the rule, applied to them, refuses nothing."""
    n = entry["episodes"]
    states = run.get("fresh")
    if not isinstance(states, dict) or set(states) != {st.label for st in SETTINGS}:
        raise ValueError(f"{method}: run {k} states no fresh maps of every setting")
    claimed, first, second = {}, {}, {}
    for st in SETTINGS:
        s = states[st.label]
        if not (isinstance(s, dict) and all(_number(s.get(x)) for x in ("claimed", "played", "maps"))):
            raise ValueError(f"{method}: run {k}'s fresh numbers of {st.label} are not numbers")
        stated = entry["settings"][st.label]
        claim = float(rescued_by_100(stated["rescue_tick"][k], stated["horizon"]).mean())
        if abs(s["claimed"] - claim) > 1e-9 or s["maps"] not in (
            fresh,
            (1 + fresh_rule.SECOND_STAGE) * fresh,
        ):
            raise ValueError(
                f"{method}: run {k}'s fresh numbers of {st.label} are not its claim on {fresh} maps"
            )
        claimed[st.label] = claim
        wins = round(s["played"] * s["maps"])
        if s["maps"] == fresh:
            first[st.label] = wins
        else:  # the first stage's share of a setting that played both is not stated: its bound
            first[st.label] = min(wins, fresh)
            second[st.label] = (wins - first[st.label], s["maps"] - fresh)
    pooled = run.get("pooled")
    if not isinstance(pooled, dict) or not _number(pooled.get("played")):
        raise ValueError(f"{method}: run {k} states no pooled numbers")
    once = [label for label in claimed if label not in second]  # their first stage is all they played
    if set(fresh_rule.suspicious(claimed, n, first, fresh)) & set(once):
        raise ValueError(f"{method}: run {k} states no second stage of a setting the rule sends to one")
    verdict = fresh_rule.judge_run(claimed, n, first, fresh, second)
    if verdict.refused:
        raise ValueError(f"{method}: by the numbers it states, the rule refuses run {k} ({verdict.reason})")
