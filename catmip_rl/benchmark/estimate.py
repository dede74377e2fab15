"""How long a grid of runs will take, said before it plays: each method timed on a few maps of each task,
the time extrapolated to the runs left.

    estimate_line(tasks, jobs=2)  # "estimate: about 2 h 10 min for 24 runs on 2 jobs (timed on 3 maps ...)"

A map's time depends on the method (a Python policy, a planner, a model) and the task (a Task-3 map
costs several Task-2 maps): what a newcomer's entry takes is measured here, on this machine, rather
than read off a table measured elsewhere. Each (method, task) is played once on :data:`TIMED_MAPS` maps
of the task's σ = 4, 5 %-noise setting (among the dearest: an estimate errs long rather than short);
the time a run spends outside its maps (building the policy, the engine) is measured too.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

from catmip_rl.benchmark.jobs import Job
from catmip_rl.evaluation.evaluate import EvalSetting, evaluate
from catmip_rl.evaluation.methods import Method
from catmip_rl.evaluation.workers import torch_threads

__all__ = ["TIMED_MAPS", "RunTime", "time_method", "estimate_line", "duration_text"]

TIMED_MAPS = (3, 12)
"""The two batches each (method, task) is timed on: a batched policy's time per map falls as its batch
grows, so the time a run takes is fitted as a fixed part plus a part per map."""


@dataclass(frozen=True)
class RunTime:
    """What one run of a method on a task costs in seconds: ``fixed`` (building the policy and engine,
    and a batch's shared work) plus ``per_map`` for each map played."""

    fixed: float
    per_map: float

    def seconds(self, maps: int) -> float:
        return self.fixed + self.per_map * maps


def time_method(
    method: Method, setting: EvalSetting, maps: int, seed: int, threads: int, sampled: bool = False
) -> RunTime:
    """Play ``method`` in ``setting`` on the first :data:`TIMED_MAPS` maps of ``seed`` (at most ``maps``)
    as a grid's run plays them (``sampled``: a learned policy's sampled pass too) and fit its time; a
    policy that fails raises here (:func:`~catmip_rl.evaluation.evaluate.evaluate`)."""
    torch_threads(threads)
    sizes = sorted({min(n, maps) for n in TIMED_MAPS})
    played, outside = [], []
    for n in sizes:
        start = time.perf_counter()
        result = evaluate(method, setting, n, seed, sampled_too=sampled)
        played.append(float(result.summary["seconds"]))
        outside.append(max(time.perf_counter() - start - played[-1], 0.0))
    per_map = played[-1] / sizes[-1]
    if len(sizes) > 1 and played[1] > played[0]:  # else timing noise: the larger batch's mean
        per_map = min(per_map, (played[1] - played[0]) / (sizes[1] - sizes[0]))
    return RunTime(played[-1] - per_map * sizes[-1] + min(outside), per_map)


def estimate_line(tasks: list[Job], jobs: int) -> str | None:
    """One line that says how long the runs of ``tasks`` still to play (those without results in their
    folder) take on ``jobs`` processes, each method timed on this machine (:func:`time_method`); None
    when every run is played."""
    left = [t for t in tasks if not (Path(t.out) / "summary.json").is_file()]
    if not left:
        return None
    fewest = min(t.episodes for t in left)
    timed: dict[tuple[str, str, int, bool], RunTime] = {}
    seconds = 0.0
    for t in left:
        key = (t.method.name, t.setting.task, t.setting.max_ma_ticks, t.sampled)  # a method's runs cost alike
        if key not in timed:
            setting = EvalSetting(t.setting.task, "4", 0.05, t.setting.max_ma_ticks)
            timed[key] = time_method(t.method, setting, fewest, t.seed, t.threads, t.sampled)
        seconds += timed[key].seconds(t.episodes)
    wall = seconds / min(jobs, len(left))
    sizes = " and ".join(str(n) for n in sorted({min(n, fewest) for n in TIMED_MAPS}))
    return (
        f"estimate: {'about ' if wall >= 60 else ''}{duration_text(wall)} for {len(left)} "
        f"run{'s' if len(left) > 1 else ''} on {jobs} job{'s' if jobs > 1 else ''} (timed on {sizes} "
        f"map{'s' if fewest > 1 else ''} of each task)"
    )


def duration_text(seconds: float) -> str:
    """``seconds`` as a person says a wait: "under a minute", "40 min", "2 h 10 min" (to 10 minutes)."""
    if seconds < 60:
        return "under a minute"
    minutes = math.ceil(seconds / 60)
    if minutes < 60:
        return f"{minutes} min"
    hours, minutes = divmod(10 * round(minutes / 10), 60)
    return f"{hours} h {minutes} min" if minutes else f"{hours} h"
