"""Success rate vs wall-clock while training AMAT, against the planning baselines on the same maps.

    python docs/figures/learning_curve.py --preset task1 --minutes 40 --run-dir runs/curve-ppo
    python docs/figures/learning_curve.py --preset task1-warm --minutes 40 --run-dir runs/curve-warm
    python docs/figures/learning_curve.py --plot runs/curve-ppo runs/curve-warm --out OUT

A training run is ``catmip train`` with a wall-clock budget (``budget_minutes``: the LR decays over it)
whose periodic evaluation (argmax and sampled actions, evaluation activation (0, 0), the preset's fixed
maps) is the curve; ``--resume`` continues a run dir. ``--plot`` draws finished runs' curves against
training minutes (evaluation excluded, the imitation warm start included) with the planners on the
same maps as horizontal lines, and writes ``OUT.csv`` / ``OUT.png``; a run started from another's
weights (``--init-from``) continues its clock, and runs evaluated on different maps (a fine-tuning
world) get a row of panels each. The CPU capability is recorded.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import numpy as np
import torch

from catmip_env.engines.episode_stats import episode_metrics
from catmip_env.engines.events import EventEngine
from catmip_env.planners.baselines import make_planner
from catmip_env.play import play
from catmip_rl.cli.args import parse_set
from catmip_rl.store.files import atomic_savefig, atomic_write_csv, atomic_write_text
from catmip_rl.training.config import TrainConfig
from catmip_rl.training.ppo import native_bf16
from catmip_rl.training.presets import make_train_config

PLANNER_LINES = ("nearest", "rrt", "random-rescue", "random-uniform")


def planner_success(cfg: TrainConfig, name: str) -> tuple[float, float]:
    """(rescued by the horizon, by tick 100) of a planner on the run's evaluation maps."""
    env_cfg = cfg.eval_env_config()
    eng = EventEngine(env_cfg, cfg.eval.eval_episodes, cfg.eval.eval_seed, goal_mode="cell")
    eng.reset()
    metrics = episode_metrics(play(eng, make_planner(name, seed=0)), env_cfg.horizon_ticks)
    return metrics["success_rate"], metrics["success_by_100"]


def curve_rows(run_dir: Path) -> list[dict]:
    """The evaluated points of a run: warm-start rounds, then PPO iterations, against minutes. A run
    started from another's weights (``init_from.json``) continues that run's clock."""
    rows = []
    name = run_dir.name
    start = _start_minutes(run_dir)
    warm = run_dir / "warm_start.csv"
    if warm.exists():
        for r in csv.DictReader(warm.open()):
            if r.get("eval/success_rate"):
                rows.append({"run": name, "phase": "warm start", "step": int(r["round"]), **_point(r, start)})
    for r in csv.DictReader((run_dir / "metrics.csv").open()):
        if r.get("eval/success_rate"):
            rows.append({"run": name, "phase": "ppo", "step": int(r["iteration"]), **_point(r, start)})
    return rows


def _start_minutes(run_dir: Path) -> float:
    """Training minutes behind a run's first iteration: those of the checkpoint it started from."""
    source = run_dir / "init_from.json"
    if not source.exists():
        return 0.0
    return float(json.loads(source.read_text()).get("elapsed_min") or 0.0)


def _point(r: dict, start: float = 0.0) -> dict:
    return {
        "minutes": start + float(r["time/elapsed_min"]),
        "success_rate": float(r["eval/success_rate"]),
        "success_by_100": float(r["eval/success_by_100"]),
        "sampled_success_rate": float(r["eval/sampled_success_rate"]),
        "sampled_success_by_100": float(r["eval/sampled_success_by_100"]),
    }


def _eval_maps(cfg: TrainConfig) -> str:
    """What a run's evaluation plays: its world (communication choices included), maps and count."""
    return json.dumps(
        [cfg.eval_env_config().to_dict(), cfg.eval.eval_episodes, cfg.eval.eval_seed], sort_keys=True
    )


def plot(runs: list[Path], out: Path) -> None:
    """Each run's curve against training minutes; runs evaluated on the same maps share a row of
    panels with the planners' success on those maps (a fine-tuning run on another world gets its own)."""
    cfgs = {run: TrainConfig.from_json((run / "config.json").read_text()) for run in runs}
    groups: dict[str, list[Path]] = {}
    for run in runs:
        groups.setdefault(_eval_maps(cfgs[run]), []).append(run)
    lines = {key: {name: planner_success(cfgs[members[0]], name) for name in PLANNER_LINES}
             for key, members in groups.items()}  # fmt: skip
    rows = [row for run in runs for row in curve_rows(run)]
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_csv(out.with_suffix(".csv"), rows)
    first = cfgs[runs[0]]
    planners = [{k: {"success_rate": v[0], "success_by_100": v[1]} for k, v in lines[key].items()}
                for key in groups]  # fmt: skip
    meta = {"cpu_capability": torch.backends.cpu.get_cpu_capability(), "native_bf16": native_bf16(),
            "eval_episodes": first.eval.eval_episodes, "eval_seed": first.eval.eval_seed,
            "planners": planners[0],
            "runs": {run.name: json.loads((run / "config.json").read_text()) for run in runs}}  # fmt: skip
    if len(groups) > 1:  # the planners on each run's own evaluation maps
        meta["planners_by_run"] = {
            run.name: planners[list(groups).index(_eval_maps(cfgs[run]))] for run in runs
        }
    atomic_write_text(out.with_suffix(".json"), json.dumps(meta, indent=2))
    _draw(runs, cfgs, groups, lines, rows, out, meta["cpu_capability"])
    print(f"wrote {out.with_suffix('.csv')}, {out.with_suffix('.json')} and {out.with_suffix('.png')}")


def _draw(runs, cfgs, groups, lines, rows, out: Path, capability: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(groups), 2, figsize=(12, 4.2 * len(groups)), sharex=True, squeeze=False)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for g, (key, members) in enumerate(groups.items()):
        cfg = cfgs[members[0]]
        env = cfg.eval_env_config()
        ranges = ["full" if c is None else f"σ={c:g}" for c in env.comm_ranges]
        comm = "full communication" if ranges == ["full"] else "communication " + " / ".join(ranges)
        for ax, key_, title in ((axes[g, 0], "success_by_100", "rescued by tick 100"),
                                (axes[g, 1], "success_rate", "rescued by the horizon")):  # fmt: skip
            for run in members:
                k = runs.index(run)
                pts = [r for r in rows if r["run"] == run.name]
                x = [r["minutes"] for r in pts]
                ax.plot(
                    x, [r[key_] for r in pts], "-o", ms=2.5, color=colours[k], label=f"{run.name} (argmax)"
                )
                ax.plot(x, [r[f"sampled_{key_}"] for r in pts], ":", color=colours[k],
                        label=f"{run.name} (sampled)")  # fmt: skip
            for (name, vals), style in zip(lines[key].items(), ("--", "-.", (0, (1, 3)), (0, (5, 2, 1, 2)))):
                ax.axhline(vals[0 if key_ == "success_rate" else 1], color="grey", ls=style, lw=1, label=name)
            ax.set_xlabel(f"training minutes ({cfg.threads} CPU thread(s), {capability})")
            ax.set_ylabel("success rate")
            ax.set_title(
                f"{cfg.env.env_preset}, {comm}, {cfg.eval.eval_episodes} fixed maps: {title}", fontsize=9
            )
            ax.set_ylim(0, 1.02)
            ax.grid(alpha=0.3)
        axes[g, 0].legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    atomic_savefig(fig, out.with_suffix(".png"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--preset", default="task1", help="training preset (catmip_rl.training.presets.TRAIN_PRESETS)"
    )
    ap.add_argument("--minutes", type=float, default=30.0, help="wall-clock budget of the training run")
    ap.add_argument("--threads", type=int, default=2, help="torch threads (1 to run two curves side by side)")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", help="TrainConfig override")
    ap.add_argument("--run-dir", help="the training run's directory")
    ap.add_argument("--resume", action="store_true", help="continue the run in --run-dir")
    ap.add_argument("--plot", nargs="+", type=Path, metavar="RUN_DIR", help="plot finished runs instead")
    ap.add_argument("--out", default="docs/figures/learning_curve", help="OUT.csv / OUT.png (--plot)")
    args = ap.parse_args()
    if args.plot:
        plot(args.plot, Path(args.out))
        return
    if not args.run_dir:
        ap.error("--run-dir is required to train (or pass --plot RUN_DIR ...)")
    from catmip_rl.training.train import train

    overrides = parse_set(args.set)
    # the budget ends the run and the LR decays over it (unless --set iterations=N runs out first)
    overrides.setdefault("iterations", 100_000)
    cfg = make_train_config(args.preset, **overrides)
    cfg = cfg.replace(budget_minutes=args.minutes, threads=args.threads)
    np.seterr(all="ignore")
    train(cfg, args.run_dir, resume=args.resume)


if __name__ == "__main__":
    main()
