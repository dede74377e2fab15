"""Evaluation protocol of the paper's Section 7: one setting, one method, N episodes.

The protocol: docs/design.md#evaluation-protocol.

    setting = EvalSetting("task2", comm="4", noise=0.05, max_ma_ticks=10)
    result = evaluate("amat:runs/a/checkpoints/latest.pt", setting, episodes=100, seed=0)
    result.summary["success_by_100"], result.curve  # success rate vs mission time
    result.write("out/eval")                         # episodes.csv/json, curve.csv, summary.json

Every method plays the maps of episode indices ``0 .. episodes-1`` of ``seed`` (a map depends only on
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
import zlib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from catmip_env import EnvConfig, make_config, render
from catmip_env.events import EventEngine
from catmip_env.planners import PLANNERS, make_planner
from catmip_env.play import EpisodeRecords, decision_metrics, episode_metrics, play, success_curve
from catmip_env.window_planner import WINDOW_KINDS, make_window_planner
from catmip_rl.amat.model import AMAT
from catmip_rl.checkpoint import load_model, resolve_model
from catmip_rl.evaluation.execution import GOAL_BYTES, AmatExecutor
from catmip_rl.files import atomic_write_csv, atomic_write_text

__all__ = [
    "EvalSetting",
    "EvalResult",
    "AmatExecutor",
    "GOAL_BYTES",
    "Method",
    "parse_method",
    "evaluate",
    "episode_rows",
    "map_hash",
    "render_episode",
    "TASKS",
    "COMM_SETTINGS",
]

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
        if not isinstance(self.max_ma_ticks, int) or self.max_ma_ticks < 1:
            raise ValueError(f"max_ma_ticks must be an int >= 1, got {self.max_ma_ticks!r}")

    def env_config(self, window: int | None = None) -> EnvConfig:
        """The task's evaluation config (activation (0, 0)); ``window`` = the policy's goal window D."""
        extra = {} if window is None else {"window": window}
        return make_config(
            self.task,
            comm_sigma=comm_sigma(self.comm),
            slam_noise=float(self.noise),
            max_ma_ticks=self.max_ma_ticks,
            **extra,
        )

    @property
    def label(self) -> str:
        comm = "full" if comm_sigma(self.comm) is None else f"sigma{self.comm}"
        return f"{self.task}-{comm}-noise{self.noise:g}-ma{self.max_ma_ticks}"


def comm_sigma(comm: str | float | None) -> float | None:
    """``"full"``/None -> None, ``"4"`` -> 4.0; anything else raises."""
    if comm is None or comm == "full":
        return None
    try:
        sigma = float(comm)
    except (TypeError, ValueError):
        raise ValueError(f"comm must be 'full' or a positive, finite range sigma, got {comm!r}") from None
    if not (sigma > 0 and math.isfinite(sigma)):
        raise ValueError(f"comm must be 'full' or a positive, finite range sigma, got {comm!r}")
    return sigma


# -- methods ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Method:
    """``name`` as written on plots; ``kind`` "planner", "window" (a planner projected into the goal
    window), "window-noheading" (the same along a heading-free path) or "amat"; ``target`` the planner's
    name or the AMAT checkpoint path; ``loop_guard`` (AMAT) executes argmax with the loop guard of
    :class:`AmatExecutor`."""

    name: str
    kind: str
    target: str
    loop_guard: bool = False


def parse_method(spec: str) -> Method:
    """``nearest`` | ``utility`` | ``rrt`` | ``apf`` | ``random-frontier`` | ``random`` |
    ``window:PLANNER`` (the planner's goals projected into the 7x7 window, the imitation teacher) |
    ``window-noheading:PLANNER`` (projected along a path that ignores the robot's heading) |
    ``amat:PATH`` | ``amat-guard:PATH`` (argmax with the loop guard) | ``NAME=...`` (PATH: a model
    file, a training checkpoint, a run dir or a shipped model's name, ``amat:task1``)."""
    spec = spec.strip()
    name = None
    if "=" in spec:
        name, spec = (s.strip() for s in spec.split("=", 1))
        if not name:
            raise ValueError(f"method {spec!r} has an empty name: write NAME={spec} or just {spec}")
    for prefix, guard in (("amat:", False), ("amat-guard:", True)):
        if spec.startswith(prefix):
            path = spec[len(prefix) :]
            if not path:
                raise ValueError(f"amat method needs a checkpoint: {prefix}PATH")
            return Method(name or prefix[:-1], "amat", str(resolve_model(path)), loop_guard=guard)
    for kind in WINDOW_KINDS:
        if spec.startswith(kind + ":"):
            planner = spec[len(kind) + 1 :]
            if planner not in PLANNERS:
                raise ValueError(f"unknown planner {planner!r} in {spec!r}; choose one of {sorted(PLANNERS)}")
            return Method(name or spec, kind, planner)
    if spec not in PLANNERS:
        raise ValueError(f"unknown method {spec!r}; choose amat:PATH or one of {sorted(PLANNERS)}")
    return Method(name or spec, "planner", spec)


def make_policy(method: Method, seed: int, model: AMAT | None = None):
    """(policy with ``act(engine)``, goal mode, window) for ``method``."""
    if method.kind == "planner":
        return make_planner(method.target, seed=seed), "cell", None
    if method.kind in WINDOW_KINDS:
        teacher = make_window_planner(method.target, seed=seed, follow_heading=WINDOW_KINDS[method.kind])
        return teacher, "window", None
    model = model if model is not None else load_model(method.target)
    return AmatExecutor(model, loop_guard=method.loop_guard), "window", model.config.window


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
    """AMAT with sampled actions on the same maps (the curve is argmax, the paper's protocol)."""

    def write(self, out: str | Path) -> Path:
        """``episodes.csv``, ``episodes.json``, ``curve.csv``, ``summary.json`` in ``out`` (atomic)."""
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_text(out / "episodes.json", json.dumps(self.episodes, indent=1))
        atomic_write_csv(out / "episodes.csv", self.episodes)
        curve = [{"tick": t, "success_rate": float(v)} for t, v in enumerate(self.curve)]
        if self.sampled_curve is not None:
            for row, v in zip(curve, self.sampled_curve):
                row["sampled_success_rate"] = float(v)
        atomic_write_csv(out / "curve.csv", curve)
        atomic_write_text(out / "summary.json", json.dumps(self.summary, indent=2))
        return out


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
) -> EvalResult:
    """Play ``episodes`` maps of ``setting`` (episode indices 0.. of ``seed``) with ``method``.

    ``model`` overrides loading the AMAT checkpoint; ``engine_hook(engine)`` is called after every
    event (for rendering or inspection). AMAT plays argmax actions (the paper's protocol: the curve and
    the plain summary keys) and, with ``sampled_too``, the same maps again with sampled actions
    (``sampled_curve``, ``sampled_*`` summary keys; a generator seeded by ``seed``).
    """
    method = parse_method(method) if isinstance(method, str) else method
    if not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"episodes must be an int >= 1, got {episodes!r}")
    policy, goal_mode, window = make_policy(method, seed, model)
    cfg = setting.env_config(window)
    passes = 2 if isinstance(policy, AmatExecutor) and sampled_too else 1
    bar = progress_bar(episodes * passes, f"{method.name} {setting.label}", progress)
    t0 = time.perf_counter()
    records, maps = _play_maps(policy, cfg, goal_mode, episodes, seed, bar, engine_hook)
    seconds = time.perf_counter() - t0
    sampled = None
    if isinstance(policy, AmatExecutor) and sampled_too:  # the same maps with sampled actions
        gen = torch.Generator().manual_seed(seed)
        sampler = AmatExecutor(policy.model, False, gen, policy.loop_guard)
        sampled = _play_maps(sampler, cfg, goal_mode, episodes, seed, bar, None)[0]
    if bar is not None:
        bar.close()
    rows = episode_rows(method, setting, seed, maps, records, sampled, policy)
    horizon = cfg.horizon_ticks
    result = EvalResult(method.name, setting, seed, rows, success_curve(records.rescue_tick, horizon))
    decisions = max(int(records.decisions.sum()), 1)
    result.summary = episode_metrics(records, horizon) | {
        "bytes_per_decision_embedding": sum(r["bytes_embedding"] for r in rows) / decisions,
        "bytes_per_decision_raw": sum(r["bytes_raw"] for r in rows) / decisions,
    }
    result.summary |= decision_metrics(records, cfg.classes)
    if sampled is not None:
        result.sampled_curve = success_curve(sampled.rescue_tick, horizon)
        m = episode_metrics(sampled, horizon)
        keys = ("success_rate", "success_by_100", "mean_rescue_tick")
        result.summary |= {f"sampled_{k}": m[k] for k in keys}
    result.summary.update(
        method=method.name,
        method_kind=method.kind,
        checkpoint=method.target if method.kind == "amat" else None,
        setting=asdict(setting),
        label=setting.label,
        seed=seed,
        seconds=seconds,
    )
    return result


def episode_rows(
    method: Method,
    setting: EvalSetting,
    seed: int,
    maps: list[str],
    records: EpisodeRecords,
    sampled: EpisodeRecords | None,
    policy,
) -> list[dict[str, Any]]:
    """One row per episode (episodes.csv / episodes.json): the setting, the map hash, the outcome,
    the decision counts, and the decision messages of an :class:`AmatExecutor` ``policy``."""

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
            "episode": e,
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
        if isinstance(policy, AmatExecutor):
            row.update(
                messages=int(policy.messages[e]),
                bytes_embedding=int(policy.bytes_embedding[e]),
                bytes_raw=int(policy.bytes_raw[e]),
            )
        else:  # planners decide on the robot's own (C-SLAM merged) belief: no decision messages
            row.update(messages=0, bytes_embedding=0, bytes_raw=0)
        rows.append(row)
    return rows


def _play_maps(
    policy, cfg: EnvConfig, goal_mode: str, episodes: int, seed: int, bar, engine_hook
) -> tuple[EpisodeRecords, list[str]]:
    """One episode on each of the maps 0 .. episodes-1 of ``seed``: (records, map hashes)."""
    eng = EventEngine(cfg, num_worlds=episodes, seed=seed, goal_mode=goal_mode)
    eng.reset(episode_indices=np.arange(episodes))
    maps = [map_hash(eng, e) for e in range(episodes)]
    if isinstance(policy, AmatExecutor):
        policy.reset_counters(episodes, eng.num_robots)
    done_before = 0 if bar is None else bar.n

    def on_event(engine: EventEngine) -> None:
        if engine_hook is not None:
            engine_hook(engine)
        if bar is not None and done_before + int(engine.state.done.sum()) > bar.n:
            bar.update(done_before + int(engine.state.done.sum()) - bar.n)

    return play(eng, policy, on_event=on_event), maps


def map_hash(engine: EventEngine, b: int) -> str:
    """CRC-32 (hex) of world ``b``'s map, target and start poses: equal hashes = the same episode."""
    st = engine.state
    parts = (st.grid[b], st.target[b], st.pos[b], st.heading[b], st.cls[b])
    return f"{zlib.crc32(b''.join(np.ascontiguousarray(p).tobytes() for p in parts)):08x}"


def render_episode(
    method: str | Method,
    setting: EvalSetting,
    path: str | Path,
    episode: int = 0,
    seed: int = 0,
    fps: int | None = None,
    max_frames: int = 600,
    model: AMAT | None = None,
) -> Path:
    """GIF of one evaluation episode (the map of ``episode`` of ``seed``, as in :func:`evaluate`),
    one frame per tick (:func:`catmip_env.render.render_episode`): robots, their goals, explored area,
    communication links; ``fps`` defaults to the env's ``metadata["render_fps"]``."""
    from catmip_env.search_rescue_v0 import SearchRescueEnv

    method = parse_method(method) if isinstance(method, str) else method
    policy, goal_mode, window = make_policy(method, seed, model)
    eng = EventEngine(setting.env_config(window), num_worlds=1, seed=seed, goal_mode=goal_mode)
    fps = SearchRescueEnv.metadata["render_fps"] if fps is None else fps
    return render.render_episode(eng, policy, path, episode, fps=fps, max_frames=max_frames)
