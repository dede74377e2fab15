"""What an evaluation records besides its curve: one row per episode (``episodes.csv``) and what the
summary says of the policy that played -- how it chose its actions, what it called of the project while
it played (an isolated policy's worker counts it) and the modules it imported from its own folder."""

from __future__ import annotations

from typing import Any

import numpy as np

from catmip_env.engines.episode_stats import EpisodeRecords
from catmip_rl.evaluation.methods import Method, own_modules

__all__ = ["episode_rows", "action_choice", "policy_calls", "policy_modules"]


def policy_calls(policy: Any) -> dict[str, int] | None:
    """What an isolated policy called of the project while it played (its worker counts: worlds built or
    reset, map sets read, maps generated, planners made and run), None for any other policy."""
    calls = getattr(policy, "calls", None)
    return calls() if getattr(policy, "isolated", False) and callable(calls) else None


def policy_modules(method: Method, policy: Any) -> list[dict[str, str]] | None:
    """The modules a ``py:`` policy imported from its own folder, with their SHA-256 (:func:`~catmip_rl.
    evaluation.methods.own_modules`, asked in the process that holds the policy); None for other methods."""
    if method.kind != "py":
        return None
    if getattr(policy, "isolated", False):
        modules = getattr(policy, "modules", None)
        return modules() if callable(modules) else None
    return own_modules(method.target)


def action_choice(policy: Any) -> str:
    """How the evaluated policy chose its actions (the summary's ``actions``): "argmax" or "sampled" for
    a policy that says (its ``deterministic`` attribute: AMAT, ``TorchRLPolicy``), else "its own" (a
    planner's rule, or a policy that does not say)."""
    deterministic = getattr(policy, "deterministic", None)
    return {True: "argmax", False: "sampled"}.get(deterministic, "its own")


def episode_rows(
    method: Method,
    setting: Any,
    seed: int,
    maps: list[str],
    records: EpisodeRecords,
    sampled: EpisodeRecords | None,
    columns: dict[str, np.ndarray],
    indices: np.ndarray | None = None,
) -> list[dict[str, Any]]:
    """One row per episode (episodes.csv / episodes.json) of ``setting`` (an :class:`~catmip_rl.evaluation.
    evaluate.EvalSetting`): the setting, the map hash, the outcome,
    the decision counts, then the policy's own ``columns`` (:func:`catmip_env.play.episode_columns`:
    its decision messages and bytes, zero for a planner)."""

    def tick(t) -> int | None:
        return int(t) if t >= 0 else None

    rows = []
    for e in range(records.num_worlds):
        row = {
            "method": method.name,
            "task": setting.task,
            "comm": setting.comm,
            "noise": setting.noise,
            "max_ma_ticks": setting.max_ma_ticks,
            "seed": seed,
            "episode": e if indices is None else int(indices[e]),
            "map_hash": maps[e],
            "rescued": bool(records.rescued[e]),
            "rescue_tick": tick(records.rescue_tick[e]),
            "target_found_tick": tick(records.found_tick[e]),
            "rescuer_informed_tick": tick(records.informed_tick[e]),
            "explored_fraction": float(records.explored_fraction[e]),
            "ticks": int(records.ticks[e]),
            "events": int(records.events[e]),
            "decisions": int(records.decisions[e].sum()),
            "stalls": int(records.stalls[e].sum()),
        }
        if sampled is not None:
            row["sampled_rescue_tick"] = tick(sampled.rescue_tick[e])
        rows.append(row)
    clash = set(columns) & set(rows[0])
    if clash:
        raise ValueError(
            f"policy {method.name}: episode_columns() names the protocol's own column(s) {sorted(clash)}"
        )
    for e, row in enumerate(rows):
        row |= {name: values[e].item() for name, values in columns.items()}
    return rows
