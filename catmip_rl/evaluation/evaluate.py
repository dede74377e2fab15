"""Evaluation protocol of the paper's Section 7 (docs/evaluation.md#the-protocol): one setting, one method,
N episodes.

    setting = EvalSetting("task2", comm="4", noise=0.05, max_ma_ticks=10)
    result = evaluate("amat:runs/a/checkpoints/latest.pt", setting, episodes=100, seed=0)
    result.summary["success_by_100"], result.curve  # success rate vs mission time
    result.write("out/eval")                         # episodes.csv/json, curve.csv, summary.json

Every method plays the maps of episode indices ``0 .. episodes-1`` of ``seed`` (or the indices it is
given: ``episode_indices``, what a leaderboard replay plays; a map depends only on
the task, the seed and the episode index), with evaluation activation (0, 0). Planners choose cells
on their own robot's belief. AMAT acts deterministically (argmax) and is executed as it would be on the
robots (:class:`AmatExecutor`): in every neighbourhood with an active robot the coordinator (lowest
id) runs encoder + decoder on the members' embeddings only; a robot out of communication decides alone.
Messages are counted per decision event: each non-coordinator member sends its embedding (d float32)
and each active non-coordinator member receives its goal; ``bytes_raw`` is the same traffic with raw
macro-observations instead of embeddings.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from catmip_env import EnvConfig, make_config
from catmip_env.config import MIN_COMM_SIGMA
from catmip_env.engines.episode_stats import EpisodeRecords, decision_metrics, episode_metrics, success_curve
from catmip_env.engines.events import EventEngine
from catmip_env.engines.world import episode_index_array
from catmip_env.maps.map_sets import check_maps, map_hash
from catmip_env.play import episode_columns, play, plays_one_world_at_a_time
from catmip_rl.evaluation.methods import (
    POLICY_SEED,
    USER_KINDS,
    Method,
    make_policy,
    method_source,
    parse_method,
    policy_files,
)
from catmip_rl.evaluation.played import Played, chunk_seed
from catmip_rl.evaluation.records import action_choice, episode_rows, policy_calls, policy_modules
from catmip_rl.evaluation.sandbox import close_policy
from catmip_rl.store.files import atomic_write_csv, atomic_write_text

if TYPE_CHECKING:  # the planners need no torch: an env-only install evaluates them
    from catmip_rl.amat.model import AMAT

__all__ = ["EvalSetting", "EvalResult", "evaluate", "TASKS", "COMM_SETTINGS"]

TASKS = ("task1", "task2", "task3")
COMM_SETTINGS = {"full": None, "4": 4.0, "2": 2.0}


@dataclass(frozen=True)
class EvalSetting:
    """One cell of the paper's grid: task, communication, SLAM noise, macro-action length."""

    task: str = "task1"
    comm: str = "full"
    """"full" or the link range sigma in cells ("4", "2", any positive finite number)."""
    noise: float = 0.0
    max_ma_ticks: int = 10

    def __post_init__(self) -> None:
        if self.task not in TASKS:
            raise ValueError(f"unknown task {self.task!r}; choose one of {list(TASKS)}")
        comm_sigma(self.comm)
        if not 0.0 <= self.noise < 1.0:
            raise ValueError(f"noise must be in [0, 1), got {self.noise!r}")
        h, ma = make_config(self.task).horizon_ticks, self.max_ma_ticks  # longer is the whole episode
        if type(ma) is not int or not 1 <= ma <= h:
            raise ValueError(f"max_ma_ticks must be an int in [1, {h}] ({self.task}'s horizon), got {ma!r}")

    def env_config(self, needs: dict | None = None, synchronous: bool = False) -> EnvConfig:
        """The task's evaluation config (activation (0, 0)); ``needs``: what the policy sets of it (an
        AMAT's goal window D and teammate memory, a reference row's full communication: ``make_policy``'s
        third answer, which wins over the setting's); ``synchronous``: every
        robot decides together every ``max_ma_ticks`` ticks (Synch-CATMiP)."""
        own = {"comm_sigma": comm_sigma(self.comm), "slam_noise": float(self.noise)}
        own |= {"max_ma_ticks": self.max_ma_ticks, "synchronous": synchronous}
        return make_config(self.task, **(own | (needs or {})))

    @property
    def label(self) -> str:
        comm = "full" if comm_sigma(self.comm) is None else f"sigma{self.comm}"
        return f"{self.task}-{comm}-noise{self.noise:g}-ma{self.max_ma_ticks}"

    @property
    def title(self) -> str:
        """The setting as a figure titles it, "Task 2, σ = 2, 5 % noise" (:func:`~catmip_rl.evaluation.
        plots.setting_title`)."""
        from catmip_rl.evaluation.plots import setting_title

        return setting_title(self)


def comm_sigma(comm: str | float | None) -> float | None:
    """``"full"``/None -> None, ``"4"`` -> 4.0; anything else (below ``MIN_COMM_SIGMA`` included) raises."""
    if comm is None or comm == "full":
        return None
    try:
        sigma = float(comm)
    except (TypeError, ValueError):
        raise ValueError(f"comm must be 'full' or a positive, finite range sigma, got {comm!r}") from None
    if not (sigma > 0 and math.isfinite(sigma)):
        raise ValueError(f"comm must be 'full' or a positive, finite range sigma, got {comm!r}")
    if sigma < MIN_COMM_SIGMA:  # a tinier range breaks the link maths
        raise ValueError(f"comm must be 'full' or a range sigma >= {MIN_COMM_SIGMA} (cells), got {comm!r}")
    return sigma


# -- results ------------------------------------------------------------------------------------
@dataclass
class EvalResult:
    method: str
    setting: EvalSetting
    seed: int
    episodes: list[dict[str, Any]]
    curve: np.ndarray
    summary: dict[str, Any] = field(default_factory=dict)
    sampled_curve: np.ndarray | None = None
    """The policy's sampled variant on the same maps (Policy.sampled; the curve is the policy itself:
    argmax for AMAT, the paper's protocol)."""

    def curve_rows(self) -> list[dict[str, Any]]:
        """The success-vs-time curve (and its sampled pass) as rows for ``plots.plot_curves``, with the
        95 % band over maps."""
        from catmip_rl.evaluation.stats import curve_band

        horizon = len(self.curve) - 1
        rows = []
        passes = [(self.method, self.curve, "rescue_tick")]
        if self.sampled_curve is not None:
            passes.append((f"{self.method} (sampled)", self.sampled_curve, "sampled_rescue_tick"))
        for method, curve, key in passes:
            ticks = np.array([[np.nan if e.get(key) is None else e[key] for e in self.episodes]], float)
            low, high = curve_band(ticks, horizon)
            at = {"panel": self.setting.label, "method": method}
            for t, v in enumerate(curve):
                rows.append(at | {"tick": t, "success_rate": float(v), "ci_low": low[t], "ci_high": high[t]})
        return rows

    def write(self, out: str | Path, curve_title: str | None = None) -> Path:
        """``episodes.csv``, ``episodes.json``, ``curve.csv``, ``summary.json`` (and ``curve.png`` with
        ``curve_title``) in ``out``: written aside, moved in together, with their record ``run.json``
        last (:func:`~catmip_rl.store.outputs.commit_results`)."""
        from catmip_rl.store.outputs import commit_results, staging_dir

        stage = staging_dir(out)
        atomic_write_text(stage / "episodes.json", json.dumps(self.episodes, indent=1))
        atomic_write_csv(stage / "episodes.csv", self.episodes)
        curve = [{"tick": t, "success_rate": float(v)} for t, v in enumerate(self.curve)]
        if self.sampled_curve is not None:
            for row, v in zip(curve, self.sampled_curve):
                row["sampled_success_rate"] = float(v)
        atomic_write_csv(stage / "curve.csv", curve)
        atomic_write_text(stage / "summary.json", json.dumps(self.summary, indent=2))
        if curve_title is not None:
            from catmip_rl.evaluation.plots import plot_curves

            plot_curves(self.curve_rows(), stage / "curve.png", title=curve_title)
        return commit_results(stage)


def progress_bar(total: int, desc: str, enabled: bool = True, unit: str = "ep", leave: bool = False):
    """A tqdm bar, or None when disabled or tqdm is missing (it comes with the rl extra)."""
    if not enabled:
        return None
    try:
        from tqdm import tqdm
    except ImportError:
        return None
    return tqdm(total=total, desc=desc, unit=unit, leave=leave, mininterval=0.5)


def evaluate(
    method: str | Method,
    setting: EvalSetting,
    episodes: int = 100,
    seed: int = 0,
    model: AMAT | None = None,
    progress: bool = False,
    engine_hook=None,
    sampled_too: bool = True,
    policy: Any = None,
    allow_other_maps: bool = False,
    threads: int = 1,
    isolated: bool | None = None,
    episode_indices: Any = None,
    chunk: bool = False,
) -> EvalResult | Played:
    """Play ``episodes`` maps of ``setting`` (episode indices 0.. of ``seed``, or the maps
    ``episode_indices`` names, any indices, in that order) with ``method``.

    ``model`` overrides loading the AMAT checkpoint; ``engine_hook(engine)`` is called after every
    event (for rendering or inspection). AMAT plays argmax actions (the paper's protocol: the curve and
    the plain summary keys) and, with ``sampled_too``, the same maps again with sampled actions
    (``sampled_curve``, ``sampled_*`` summary keys; a generator seeded by ``seed``).

    ``policy``: your own policy object (PettingZoo or engine level, or a TorchRL module; see
    :mod:`~catmip_rl.evaluation.user_policy`), played under the name ``method``:
    ``evaluate("mine", setting, policy=MyPolicy())``. The maps are checked against the frozen map sets
    (:mod:`catmip_env.maps.map_sets`) before any is played: other maps raise ``MapSetMismatch`` unless
    ``allow_other_maps`` (the summary's ``map_set_*`` keys say what was found). ``threads``: the env's
    worlds stepped on that many threads (the same results). ``isolated``: a ``py:`` policy plays in a
    worker process that holds no engine (:mod:`~catmip_rl.evaluation.sandbox`; None: as the
    :class:`Method` says, isolated unless it says otherwise); ``isolated=False`` plays it in this
    process, for tests and debugging. The project's planners and models, and ``policy``, play here.
    ``chunk``: return the play unsummarised (:class:`~catmip_rl.evaluation.played.Played`), one chunk of
    an evaluation that a job runner merges (:func:`~catmip_rl.evaluation.played.merge_played`,
    :func:`result_of`).
    """
    if policy is not None:
        if not isinstance(method, str) or not method.strip() or ":" in method or "=" in method:
            raise ValueError(f"with policy=..., method is the policy's name (a plain word), got {method!r}")
        method = Method(method.strip(), "policy", type(policy).__name__)
    method = parse_method(method) if isinstance(method, str) else method
    if episode_indices is not None:
        episodes = len(episode_indices)
    if not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"episodes must be an int >= 1, got {episodes!r}")
    indices = np.arange(episodes) if episode_indices is None else episode_index_array(episode_indices)
    if isolated is not None and method.kind in ("py", "policy"):
        if isolated and method.kind == "policy":
            raise ValueError(
                "isolated=True plays a py:FILE.py:FACTORY policy; an object lives in this process"
            )
        method = replace(method, isolated=bool(isolated))
    sync = method.synchronous
    policy, goal_mode, needs = make_policy(method, setting.env_config(None, sync), seed, model, policy)
    try:
        return _evaluate(
            method,
            setting,
            indices,
            seed,
            policy,
            goal_mode,
            needs,
            progress,
            engine_hook,
            sampled_too,
            allow_other_maps,
            threads,
            chunk,
        )
    finally:
        close_policy(policy)


def _evaluate(
    method,
    setting,
    indices,
    seed,
    policy,
    goal_mode,
    needs,
    progress,
    engine_hook,
    sampled_too,
    allow_other_maps,
    threads,
    chunk,
) -> EvalResult | Played:
    sync = method.synchronous
    cfg = setting.env_config(needs, sync)
    episodes = len(indices)
    engine = EventEngine(cfg, num_worlds=episodes, seed=seed, goal_mode=goal_mode, threads=threads)
    engine.reset(episode_indices=indices)
    maps = [map_hash(engine, e) for e in range(episodes)]
    check_maps(setting.task, seed, maps, allow_other_maps, indices)  # other maps: raise before playing
    sampled_variant = getattr(policy, "sampled", None) if sampled_too else None  # the Policy protocol's hook
    passes = 2 if sampled_variant is not None else 1
    both = " (argmax + sampled)" if passes > 1 else ""  # the bar counts the episodes of both passes
    bar = progress_bar(episodes * passes, f"{method.name} {setting.label}{both}", progress)
    t0 = time.perf_counter()
    records = _play_maps(policy, engine, bar, engine_hook)
    seconds = time.perf_counter() - t0
    sampled = None
    if sampled_variant is not None:  # the same maps with sampled actions
        engine.reset(episode_indices=indices)
        first = int(indices[0]) if len(indices) else 0
        sampled = _play_maps(sampled_variant(_sampled_seed(method, seed, first)), engine, bar, None)
    if bar is not None:
        bar.close()
    try:
        columns = episode_columns(policy, episodes)
    except ValueError as err:
        raise ValueError(f"policy {method.name}: {err}") from None
    info = {
        "actions": action_choice(policy),
        "policy_files": policy_files(policy),
        "policy_calls": policy_calls(policy),
        "policy_modules": policy_modules(method, policy),
    }
    played = Played(
        method, setting, seed, cfg, indices, maps, records, sampled, columns, info, seconds, allow_other_maps
    )
    return played if chunk else result_of(played)


def result_of(played: Played) -> EvalResult:
    """The result of ``played`` (one play of some maps, or the merged chunks of one evaluation,
    :func:`~catmip_rl.evaluation.played.merge_played`): its rows, curves and summary."""
    method, setting, seed, cfg = played.method, played.setting, played.seed, played.cfg
    records = played.records
    map_set = check_maps(setting.task, seed, played.maps, played.allow_other_maps, played.indices)
    rows = episode_rows(
        method, setting, seed, played.maps, records, played.sampled, played.columns, played.indices
    )
    horizon = cfg.horizon_ticks
    result = EvalResult(method.name, setting, seed, rows, success_curve(records.rescue_tick, horizon))
    decisions = max(int(records.decisions.sum()), 1)
    result.summary = episode_metrics(records, horizon) | {
        "bytes_per_decision_embedding": sum(r["bytes_embedding"] for r in rows) / decisions,
        "bytes_per_decision_raw": sum(r["bytes_raw"] for r in rows) / decisions,
    }
    result.summary |= decision_metrics(records, cfg.classes)
    if played.sampled is not None:
        result.sampled_curve = success_curve(played.sampled.rescue_tick, horizon)
        m = episode_metrics(played.sampled, horizon)
        keys = ("success_rate", "success_by_100", "mean_rescue_tick")
        result.summary |= {f"sampled_{k}": m[k] for k in keys}
    info = played.info
    result.summary.update(
        method=method.name,
        method_kind=method.kind,
        target=method.target,
        actions=info["actions"],
        sampled_pass=played.sampled is not None,
        loop_guard=method.loop_guard,
        clean_occupancy=method.clean_occupancy,
        synchronous=method.synchronous,
        isolated=method.isolated,
        checkpoint=method.target if method.kind == "amat" else None,
        policy=method.target if method.kind in ("py", "policy") else None,
        source=method_source(method),
        policy_files=info["policy_files"],
        policy_calls=info["policy_calls"],
        policy_modules=info["policy_modules"],
        setting=asdict(setting),
        label=setting.label,
        seed=seed,
        seconds=played.seconds,
        **map_set.as_dict(),
    )
    return result


def _sampled_seed(method: Method, seed: int, first: int) -> int:
    """The seed of a policy's sampled pass over maps from index ``first`` on: the map set's
    (:func:`~catmip_rl.evaluation.played.chunk_seed`: keyed per chunk) for the project's models,
    :data:`POLICY_SEED` for a user's policy (told nothing of the maps)."""
    return POLICY_SEED if method.kind in USER_KINDS else chunk_seed(seed, first)


def _play_maps(policy, engine: EventEngine, bar, engine_hook) -> EpisodeRecords:
    """Play the episodes ``engine`` was just reset to (world e = map e) to their end: their records.

    A policy that plays one world at a time (a PettingZoo-level one) plays them one after another on a
    one-world engine, its ``reset()`` called before each (as in a PettingZoo loop); every other policy
    plays them all at once, its ``start_episodes(num_worlds, num_robots)`` called first if it has one
    (the :class:`~catmip_env.play.Policy` protocol)."""
    if hasattr(policy, "start_episodes"):
        policy.start_episodes(engine.num_worlds, engine.num_robots)
    done_before = 0 if bar is None else bar.n

    def on_event(eng: EventEngine, offset: int = 0) -> None:
        if engine_hook is not None:
            engine_hook(eng)
        done = done_before + offset + int(eng.state.done.sum())
        if bar is not None and done > bar.n:
            bar.update(done - bar.n)

    if hasattr(policy, "bound_records"):  # a reference computed from the maps (walk-bound)
        records = policy.bound_records(engine)
        on_event(engine, engine.num_worlds - int(engine.state.done.sum()))
        return records
    if not plays_one_world_at_a_time(policy):
        return play(engine, policy, on_event=on_event)
    # a world's episode depends only on the seed, its index and the actions (catmip_env.kernels.rng)
    one = EventEngine(engine.cfg, num_worlds=1, seed=engine.world.base_seed, goal_mode=engine.goal_mode)
    records = []
    for e in range(engine.num_worlds):
        one.reset(episode_indices=engine.state.episode[e : e + 1])
        policy.reset()
        records.append(play(one, policy, on_event=lambda eng, e=e: on_event(eng, e)))
    return EpisodeRecords.concat(records)
