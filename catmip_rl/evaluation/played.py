"""What playing some maps gives before it is summarised (:class:`Played`), and several such plays of one
evaluation's map chunks merged in map order (:func:`merge_played`).

A chunk of maps is played wherever a job runner sends it (:mod:`~catmip_rl.benchmark.runner`: this
process, a local pool, a Ray worker); its :class:`Played` comes back and the chunks of one evaluation
are merged and summarised once (:func:`~catmip_rl.evaluation.evaluate.result_of`), so that the files an
evaluation writes do not depend on how its maps were split or where they were played (only the
``seconds`` it took does).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from catmip_env.config import EnvConfig
from catmip_env.engines.episode_stats import EpisodeRecords

__all__ = ["Played", "merge_played", "chunk_seed"]


@dataclass(frozen=True)
class Played:
    """The maps ``indices`` of ``seed`` played by ``method`` in ``setting`` (an
    :class:`~catmip_rl.evaluation.evaluate.EvalSetting`) under ``cfg``: their hashes, records, the
    sampled pass's records (or None), the policy's per-episode columns, what the policy says of itself
    (``info``: actions, policy_files, policy_calls, policy_modules) and the seconds the play took."""

    method: Any
    setting: Any
    seed: int
    cfg: EnvConfig
    indices: np.ndarray
    maps: list[str]
    records: EpisodeRecords
    sampled: EpisodeRecords | None
    columns: dict[str, np.ndarray]
    info: dict[str, Any]
    seconds: float
    allow_other_maps: bool = False


def merge_played(parts: list[Played]) -> Played:
    """The plays of one evaluation's chunks as one, in the order given (map order); ValueError if they
    are not chunks of one evaluation (method, setting, seed, config, what the policy says of itself but
    its call counts, which are summed)."""
    if not parts:
        raise ValueError("no chunk to merge")
    first = parts[0]
    same = ("method", "setting", "seed", "cfg", "allow_other_maps")
    for p in parts[1:]:
        differs = [k for k in same if getattr(p, k) != getattr(first, k)]
        fixed = {k: v for k, v in p.info.items() if k != "policy_calls"}
        if differs or fixed != {k: v for k, v in first.info.items() if k != "policy_calls"}:
            raise ValueError(f"chunks of different evaluations: {differs or ['what the policy says']}")
        if (p.sampled is None) != (first.sampled is None):
            raise ValueError("chunks of different evaluations: a sampled pass in some only")
    if len(parts) == 1:
        return first
    calls = [p.info.get("policy_calls") for p in parts]
    info = dict(first.info)
    if any(c is not None for c in calls):
        summed: dict[str, int] = {}
        for c in calls:
            for key, n in (c or {}).items():
                summed[key] = summed.get(key, 0) + int(n)
        info["policy_calls"] = summed
    return replace(
        first,
        indices=np.concatenate([p.indices for p in parts]),
        maps=[m for p in parts for m in p.maps],
        records=EpisodeRecords.concat([p.records for p in parts]),
        sampled=None if first.sampled is None else EpisodeRecords.concat([p.sampled for p in parts]),
        columns={k: np.concatenate([p.columns[k] for p in parts]) for k in first.columns},
        info=info,
        seconds=float(sum(p.seconds for p in parts)),
    )


def chunk_seed(seed: int, first: int) -> int:
    """The seed of a sampled pass over the maps from episode index ``first`` on: ``seed`` itself for the
    maps from 0 (one chunk, or the first: as an evaluation of maps 0.. always drew), a seed derived from
    (``seed``, ``first``) for a later chunk. A random stream is keyed per chunk, never per batch, so
    the chunks of one evaluation draw the same wherever they are played."""
    if first == 0:
        return int(seed)
    state = np.random.SeedSequence(int(seed), spawn_key=(int(first),)).generate_state(2, np.uint32)
    return int(state[0]) | (int(state[1] & 0x7FFFFFFF) << 32)
