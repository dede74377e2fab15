"""Issue 78's gates for ``rrt-relay-deadline`` (catmip_env/planners/deadline.py), on fresh seeds, paired on the
same maps as ``rrt-relay-coord``. From the repository root:

    python run-records/deadline-gates/gates.py g1 [--decisions 2000]      # offline: the posterior's calibration
    python run-records/deadline-gates/gates.py g2 [--maps 500] [--arms optimistic,posterior]
    python run-records/deadline-gates/gates.py g3 [--maps 1500] [--arms ...]
    python run-records/deadline-gates/gates.py report

Every play is one chunk of 100 maps (maps k*100 .. k*100+99 of the gate's seed), written at once to
``<gate>/<setting>-<arm>-<k>.json`` (rescue ticks per map); a chunk already there is not played again, so a
run resumes where it stopped and the chunks are committed before a sitting ends. Seeds: G1 48101, G2 48201,
G3 48301 (never 0, 1, 2, 1000, 12345, 20261201, 9100, 9200, 31100-31700, nor any other the project used).

Gates, set before the runs (issue 78):
* G1: on ~2,000 explorer decisions with true labels (is the target beyond this cluster?), the posterior's
  Brier score >= 10 % better than the optimistic estimate's, and its choice differs in >= 15 % of them; else
  the posterior arm stops (the optimistic arm goes on: it is the ablation of the deadline objective).
* G2: 500 maps x the four sigma = 2 settings, each arm against rrt-relay-coord: stop an arm whose pooled
  upper 95 % bound (paired bootstrap over maps, stratified by setting) is below +0.03.
* G3: 1,500 maps of each sigma = 2 setting and of Task 2 and 3 with full communication: pooled over the four
  >= +0.03 with its lower bound above 0, none of the four below -0.01, >= -0.01 with full communication,
  rescued by the horizon >= 0.99 everywhere.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from catmip_env.events import EventEngine
from catmip_env.planners.baselines import make_planner
from catmip_env.planners.deadline import DeadlinePlanner, target_mass
from catmip_env.play import play
from catmip_rl.evaluation.evaluate import EvalSetting

HERE = Path(__file__).resolve().parent
SEEDS = {"g1": 48101, "g2": 48201, "g3": 48301}
SIGMA2 = [("task2", "2", 0.0), ("task2", "2", 0.05), ("task3", "2", 0.0), ("task3", "2", 0.05)]
FULL = [("task2", "full", 0.0), ("task3", "full", 0.0)]
CHUNK = 100


def label(setting: tuple) -> str:
    task, comm, noise = setting
    return f"{task}-{comm}-noise{noise}"


ARMS = {  # the arms, fixed before G2: the planner as the issue writes it, and without staging the rescuers
    "posterior": {"world": "posterior"},
    "optimistic": {"world": "optimistic"},
    "optimistic-nostage": {"world": "optimistic", "stage": False},
}


def make(arm: str, seed: int):
    if arm == "base":
        return make_planner("rrt-relay-coord", seed)
    return DeadlinePlanner(seed, **ARMS[arm])


def play_chunk(gate: str, setting: tuple, arm: str, k: int) -> dict:
    """Rescue ticks of maps k*100 .. k*100+99 of the gate's seed (-1: not rescued), written once."""
    path = HERE / gate / f"{label(setting)}-{arm}-{k}.json"
    if path.exists():
        return json.loads(path.read_text())
    seed = SEEDS[gate]
    cfg = EvalSetting(*setting).env_config()
    engine = EventEngine(cfg, num_worlds=CHUNK, seed=seed, goal_mode="cell")
    engine.reset(episode_indices=np.arange(k * CHUNK, (k + 1) * CHUNK))
    t0 = time.perf_counter()
    rec = play(engine, make(arm, seed))
    out = {"setting": label(setting), "arm": arm, "chunk": k, "seed": seed,
           "rescue_tick": np.asarray(rec.rescue_tick).astype(int).tolist(),
           "horizon": cfg.horizon_ticks, "seconds": round(time.perf_counter() - t0, 1)}  # fmt: skip
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(out))
    os.replace(tmp, path)
    print(f"{gate} {label(setting)} {arm} chunk {k}: {np.mean(by100(out)):.3f} in {out['seconds']} s", flush=True)
    return out


def by100(chunk: dict) -> np.ndarray:
    t = np.asarray(chunk["rescue_tick"])
    return ((t >= 0) & (t <= 100)).astype(float)


def paired_pooled(diffs: list[np.ndarray], n_boot: int = 10_000, seed: int = 0) -> tuple[float, float, float]:
    """Mean of the per-setting mean differences and its 95 % bootstrap interval (maps resampled within each
    setting: a stratified paired bootstrap)."""
    rng = np.random.default_rng(seed)
    boots = np.zeros(n_boot)
    for d in diffs:
        boots += d[rng.integers(len(d), size=(n_boot, len(d)))].mean(axis=1)
    boots /= len(diffs)
    mean = float(np.mean([d.mean() for d in diffs]))
    return mean, float(np.quantile(boots, 0.025)), float(np.quantile(boots, 0.975))


def gate_play(gate: str, settings: list, arms: list[str], maps: int) -> dict:
    results = {}
    for setting in settings:
        for arm in ["base", *arms]:
            chunks = [play_chunk(gate, setting, arm, k) for k in range(maps // CHUNK)]
            results[(label(setting), arm)] = chunks
    return results


def summary(gate: str, settings: list, arms: list[str], maps: int) -> dict:
    res = gate_play(gate, settings, arms, maps)
    out = {}
    for arm in arms:
        diffs, rows = [], {}
        for setting in settings:
            key = label(setting)
            a = np.concatenate([by100(c) for c in res[(key, arm)]])
            b = np.concatenate([by100(c) for c in res[(key, "base")]])
            t = np.concatenate([np.asarray(c["rescue_tick"]) for c in res[(key, arm)]])
            diffs.append(a - b)
            rows[key] = {"arm": float(a.mean()), "base": float(b.mean()), "diff": paired_pooled([a - b]),
                         "rescued_by_horizon": float((t >= 0).mean()), "maps": len(a)}  # fmt: skip
        out[arm] = {"settings": rows, "pooled": paired_pooled(diffs)}
    return out


def g1(decisions: int) -> dict:
    """Explorer decisions of the optimistic arm on fresh maps (G1's seed): each cluster's chance that the
    target lies beyond it under both worlds, the true label, and each world's choice."""
    path = HERE / "g1" / "decisions.json"
    if path.exists():
        rows = json.loads(path.read_text())
    else:
        rows = []
        planner = Recorder(SEEDS["g1"], rows)
        for k, setting in enumerate(SIGMA2 * 10):
            if len(rows) >= decisions:
                break
            cfg = EvalSetting(*setting).env_config()
            engine = EventEngine(cfg, num_worlds=20, seed=SEEDS["g1"], goal_mode="cell")
            engine.reset(episode_indices=np.arange(k * 20, (k + 1) * 20))
            play(engine, planner)
            print(f"g1: {label(setting)} maps {k * 20}..{k * 20 + 19}: {len(rows)} decisions", flush=True)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(rows))
    brier = {w: float(np.mean([r[w]["brier"] for r in rows])) for w in ("optimistic", "posterior")}
    changed = float(np.mean([r["optimistic"]["pick"] != r["posterior"]["pick"] for r in rows]))
    better = 1 - brier["posterior"] / brier["optimistic"]
    return {"decisions": len(rows), "brier": brier, "brier_improvement": better, "changed": changed,
            "passes": bool(better >= 0.10 and changed >= 0.15)}  # fmt: skip


class Recorder(DeadlinePlanner):
    """The optimistic arm, recording at every scored explorer decision both worlds' cluster chances."""

    def __init__(self, seed: int, rows: list) -> None:
        super().__init__(seed, world="optimistic")
        self.rows = rows

    def _explore(self, ctx, goals, regions, fields, mass):
        tr, tc = ctx.target
        truth = int(regions[tr, tc])
        row = {}
        for world in ("posterior", "optimistic"):  # the optimistic one last: its pick is played
            m = mass if world == "optimistic" else target_mass(ctx, "posterior", self.corner(ctx))
            pick = super()._explore(ctx, goals, regions, fields, m)
            beyond = self.last["beyond"]
            y = (np.arange(len(goals)) == truth).astype(float)
            row[world] = {"brier": round(float(((beyond - y) ** 2).sum()), 4), "pick": -1 if pick is None else pick}
        self.rows.append(row)
        return pick


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("gate", choices=["g1", "g2", "g3", "report"])
    p.add_argument("--decisions", type=int, default=2000)
    p.add_argument("--maps", type=int, default=None)
    p.add_argument("--arms", default="optimistic,posterior")
    a = p.parse_args()
    arms = a.arms.split(",")
    if a.gate == "g1":
        result = g1(a.decisions)
    elif a.gate == "g2":
        result = summary("g2", SIGMA2, arms, a.maps or 500)
    elif a.gate == "g3":
        result = {"sigma2": summary("g3", SIGMA2, arms, a.maps or 1500),
                  "full": summary("g3", FULL, arms, a.maps or 1500)}  # fmt: skip
    else:
        result = {}
    print(json.dumps(result, indent=1))
    if a.gate != "report":
        (HERE / f"{a.gate}.json").write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
