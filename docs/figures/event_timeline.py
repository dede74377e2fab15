"""Draw docs/figures/event_timeline.png: who runs, waits and decides in a real asynchronous episode.

    python docs/figures/event_timeline.py [--seed 3] [--ticks 60]

Runs one ``train``-preset episode (activation (2, 5), macro-actions of at most 10 ticks) with random
valid window goals and reconstructs every robot's macro-actions and standby spells from the events:
at an activation after ``w`` waiting ticks, the previous macro-action ended ``w`` ticks earlier.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from catmip_env import PRESETS  # noqa: E402
from catmip_env.engines.events import EventEngine, random_valid_actions  # noqa: E402
from catmip_env.kernels.activation import M_WAIT  # noqa: E402


def trace(seed: int, ticks: int):
    eng = EventEngine(PRESETS["train"], 1, seed=seed)
    eng.reset()
    rng = np.random.default_rng(seed)
    events = [(0, eng.active[0].copy(), np.zeros(eng.num_robots, np.int64))]
    while eng.state.ticks[0] < ticks and not eng.state.done[0]:
        eng.step(random_valid_actions(eng.masks, rng))
        events.append((int(eng.state.ticks[0]), eng.active[0].copy(), eng.mstate[0, :, M_WAIT].copy()))
    names = [eng.cfg.classes[c].name for c in eng.state.cls[0]]
    return events, names


def draw(events, names, path: Path) -> None:
    n = len(names)
    fig, ax = plt.subplots(figsize=(10, 0.8 + 0.7 * n))
    last = [0] * n
    for t, active, wait in events[1:]:
        for i in np.flatnonzero(active):
            end = t - wait[i]
            ax.barh(i, end - last[i], left=last[i], color="tab:blue", height=0.5)
            ax.barh(i, t - end, left=end, color="tab:orange", height=0.5, hatch="//")
            last[i] = t
    for t, active, _ in events:
        ax.axvline(t, color="grey", lw=0.6, alpha=0.5)
        for i in np.flatnonzero(active):
            ax.plot(t, i, "kv", ms=7)
    ax.set_yticks(range(n), [f"robot_{i} ({name})" for i, name in enumerate(names)])
    ax.invert_yaxis()
    ax.set_xlabel("tick")
    ax.set_title(
        "Asynchronous decisions: macro-action (blue), standby (orange), activation (▼), events (grey)"
    )
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--ticks", type=int, default=60)
    ap.add_argument("--out", default=str(Path(__file__).with_name("event_timeline.png")))
    args = ap.parse_args()
    events, names = trace(args.seed, args.ticks)
    draw(events, names, Path(args.out))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
