"""One env stepped alone through its Python API, beside POGEMA (the closest grid-MARL peer), in one run.

Env-steps per second of ``step()`` alone (``reset()`` timed apart; the random valid actions drawn before
the timing, for every step at once where they do not depend on the observation), each setting in a fresh
process, the two envs interleaved round by round:

* ``search_rescue_v0`` at the primitive level (one step = one tick, ``Discrete(4)``), the float dict
  observations: Task 2 (20 x 20, 3 robots) and Task 3 (32 x 32, 6 robots); the macro level (one step =
  one decision event) timed beside it for the record;
* POGEMA's ``pogema_v0(GridConfig(size, num_agents, seed))`` with its defaults (obstacle density 0.3,
  observation radius 5, 64-step episodes), actions ``0..4``: 20 x 20 with 3 agents, 32 x 32 with 6.

POGEMA 1.4.0 pins gymnasium 0.28, which PettingZoo >= 1.25 cannot share, so it runs in an interpreter of
its own (``make bench-peer`` makes ``.venv-pogema`` with it and runs this script); without one the
script times ``search_rescue_v0`` alone and says so.

    python benchmarks/bench_peer.py [--pogema-python .venv-pogema/bin/python] [--steps 20000] \
        [--rounds 3] [--out benchmarks/results/peer.json]

Writes ``--out`` (the machine, ``common.machine_info``; POGEMA's version): per setting and round the
steps/s, the median over the rounds, and the ratio of the medians (the target: >= 1.5).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve()
PAIRS = [  # (our preset, POGEMA's size and agents): the same grid and team
    ("task2", 20, 3),
    ("task3", 32, 6),
]
DEFAULT_POGEMA = HERE.parent.parent / ".venv-pogema" / "bin" / "python"


def time_catmip(preset: str, level: str, steps: int) -> dict:
    """Steps/s of ``search_rescue_v0`` (one world) and resets/s, after a warm-up episode."""
    import numpy as np

    from catmip_env import search_rescue_v0
    from catmip_env.engines.events import random_valid_actions

    env = search_rescue_v0.parallel_env(preset=preset, level=level)
    agents = env.possible_agents
    rng = np.random.default_rng(0)
    env.reset(seed=0)
    for _ in range(50):  # warm-up: the kernels are loaded from numba's cache on first use
        if not env.agents:
            env.reset()
        env.step({a: 3 if level == "primitive" else 24 for a in agents})
    obs, _ = env.reset(seed=1)
    stepped = resets = 0
    step_s = reset_s = 0.0
    drawn = [dict(zip(agents, row)) for row in rng.integers(0, 4, (steps, len(agents))).tolist()]
    while stepped < steps:
        if level == "primitive":
            actions = drawn[stepped]
        else:  # valid goals depend on the observation: drawn at each step
            masks = np.stack([obs[a]["action_mask"] for a in agents])
            actions = dict(zip(agents, random_valid_actions(masks[None], rng)[0].tolist()))
        t0 = time.perf_counter()
        obs, *_ = env.step(actions)
        step_s += time.perf_counter() - t0
        stepped += 1
        if not env.agents:
            t0 = time.perf_counter()
            obs, _ = env.reset()
            reset_s += time.perf_counter() - t0
            resets += 1
    return {"steps_per_s": stepped / step_s, "resets_per_s": resets / reset_s if resets else None}


def time_pogema(size: int, agents: int, steps: int) -> dict:
    """Steps/s of POGEMA's env (its defaults) and resets/s, after a warm-up episode."""
    import numpy as np
    import pogema
    from pogema import GridConfig, pogema_v0

    env = pogema_v0(GridConfig(size=size, num_agents=agents, seed=0))
    env.reset()
    for _ in range(64):
        _, _, term, trunc, _ = env.step([0] * agents)
        if all(term) or all(trunc):
            env.reset()
    env.reset()
    drawn = np.random.default_rng(0).integers(0, 5, (steps, agents)).tolist()
    stepped = resets = 0
    step_s = reset_s = 0.0
    while stepped < steps:
        actions = drawn[stepped]
        t0 = time.perf_counter()
        _, _, term, trunc, _ = env.step(actions)
        step_s += time.perf_counter() - t0
        stepped += 1
        if all(term) or all(trunc):
            t0 = time.perf_counter()
            env.reset()
            reset_s += time.perf_counter() - t0
            resets += 1
    return {
        "steps_per_s": stepped / step_s,
        "resets_per_s": resets / reset_s if resets else None,
        "version": pogema.__version__,
    }


def worker(argv: list[str]) -> None:
    kind, *rest = argv
    if kind == "catmip":
        preset, level, steps = rest
        out = time_catmip(preset, level, int(steps))
    else:
        size, agents, steps = rest
        out = time_pogema(int(size), int(agents), int(steps))
    print(json.dumps(out))


def measure(python: str, args: list[str]) -> dict:
    """One timing in a fresh process of ``python``; a failure ends the run with its stderr."""
    proc = subprocess.run([python, str(HERE), "--worker", *args], capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        sys.exit(f"bench_peer: {' '.join(args)} failed under {python}:\n{proc.stderr.strip()[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def pogema_python(path: str | None) -> str | None:
    """The interpreter POGEMA is installed in, or None (said, with how to install it)."""
    python = Path(path) if path else DEFAULT_POGEMA
    if python.exists():
        check = subprocess.run([str(python), "-c", "import pogema"], capture_output=True, check=False)
        if check.returncode == 0:
            return str(python)
    print(
        f"POGEMA is not installed for {python}: timing search_rescue_v0 alone "
        f"(`make bench-peer` installs pogema==1.4.0 in .venv-pogema and runs this script)"
    )
    return None


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--worker":
        worker(sys.argv[2:])
        return
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pogema-python", default=None, help="an interpreter with pogema (default .venv-pogema)")
    ap.add_argument("--steps", type=int, default=20_000, help="timed steps per setting and round")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", default="benchmarks/results/peer.json")
    args = ap.parse_args()
    sys.path.insert(0, str(HERE.parent))
    from common import machine_info, write_json

    peer = pogema_python(args.pogema_python)
    rows: dict[tuple, dict] = {}
    for r in range(args.rounds):
        for preset, size, agents in PAIRS:
            timings = [
                (("search_rescue_v0", preset, "primitive"), sys.executable, ["catmip", preset, "primitive"]),
                (("search_rescue_v0", preset, "macro"), sys.executable, ["catmip", preset, "macro"]),
            ]
            if peer:
                timings.insert(1, (("pogema", preset, "primitive"), peer, ["pogema", str(size), str(agents)]))
            for key, python, what in timings:
                steps = args.steps if key[2] == "primitive" else max(args.steps // 10, 500)
                got = measure(python, [*what, str(steps)])
                row = rows.setdefault(key, {"env": key[0], "setting": preset, "level": key[2], "rounds": []})
                row.setdefault("version", got.get("version"))
                row["rounds"].append(got)
                print(f"round {r + 1}: {key[0]:16s} {preset} {key[2]:9s} {got['steps_per_s']:9.0f} steps/s")
    table = []
    for row in rows.values():
        row["steps_per_s"] = statistics.median(x["steps_per_s"] for x in row["rounds"])
        table.append(row)
    ratios = []
    for preset, size, agents in PAIRS:
        ours = rows[("search_rescue_v0", preset, "primitive")]
        theirs = rows.get(("pogema", preset, "primitive"))
        ratio = ours["steps_per_s"] / theirs["steps_per_s"] if theirs else None
        per_round = (
            [a["steps_per_s"] / b["steps_per_s"] for a, b in zip(ours["rounds"], theirs["rounds"])]
            if theirs
            else []
        )
        ratios.append(
            {"setting": preset, "grid": size, "agents": agents, "ratio": ratio, "per_round": per_round}
        )
        if ratio is not None:
            print(
                f"{preset} ({size}x{size}, {agents} agents): {ratio:.2f}x POGEMA "
                f"(rounds {', '.join(f'{x:.2f}' for x in per_round)})"
            )
    write_json(
        args.out,
        {
            "machine": machine_info(),
            "steps": args.steps,
            "rounds": args.rounds,
            "peer": bool(peer),
            "rows": table,
            "ratios": ratios,
        },
    )


if __name__ == "__main__":
    main()
