"""Relay-focused DAgger of rrt-relay-heading (experiment, outside the repository).

Every round: the student plays the mixture (teacher executes with prob beta), rrt-relay-heading labels every
active robot and records which labels its relay rule chose. Steps: CE over a uniform batch of events plus CE
over the relay robots of a batch drawn from events with a relay label (weight W). Reports the student's
agreement on relay labels and on all labels, before training (round 0's rollout) and after each round.
usage: relaydag.py START OUT ROUNDS STEPS [W] [EPISODE_SCALE] [LR]
"""

import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from catmip_env.planners import make_planner
from catmip_rl.checkpoint import load_model, save_model
from catmip_rl.training.collect import Collector
from catmip_rl.training.imitation import DemoBuffer, imitation_loss
from catmip_rl.training.presets import make_train_config

start, out, rounds, steps = sys.argv[1], Path(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
w = float(sys.argv[5]) if len(sys.argv) > 5 else 1.0
scale = float(sys.argv[6]) if len(sys.argv) > 6 else 1.0
out.mkdir(parents=True, exist_ok=True)
torch.set_num_threads(1)
cfg = make_train_config("general-heading")
model = load_model(start)
teacher = make_planner("rrt-relay-heading", seed=11)


class Rec:
    def __init__(self):
        self.rec = []

    def act(self, eng):
        a = teacher.act(eng)
        self.rec.append(teacher.relayed & eng.active)
        return a


cols = [
    Collector(env, max(8, int(n * scale)), 11, cfg.gamma, goal_mode="cell") for env, n in cfg.world_configs()
]
bufs = [DemoBuffer(10**7) for _ in cols]
relay = [np.zeros((0, cols[k].engine.num_robots), bool) for k in range(len(cols))]
gen = torch.Generator().manual_seed(11)
rng = np.random.default_rng(11)
opt = torch.optim.Adam(model.parameters(), lr=float(sys.argv[7]) if len(sys.argv) > 7 else 3e-4, eps=1e-5)
log = open(out / "log.jsonl", "a")
episodes = 900_000  # far from the gate seeds' indices (own seed 11 anyway)


def weighted(xs):
    """Mean of (agreement, labels) pairs weighted by their labels."""
    return sum(a * n for a, n in xs) / max(1, sum(n for _, n in xs))


def agreement(k, idx, rel_only):
    b = bufs[k].batch(idx, model.config.n_classes, "cpu")
    if rel_only:
        b["active"] = torch.from_numpy(relay[k][idx])
    with torch.no_grad():
        _, st = imitation_loss(model, b)
    return st["imitation/accuracy"], int(b["active"].sum())


for r in range(rounds + 1):
    t0 = time.perf_counter()
    beta = 0.0 if r == 0 else 0.5 ** (r - 1)
    fresh = []
    for k, col in enumerate(cols):
        lab = Rec()
        model.eval()
        ro = col.collect(model, episodes, gen, labeler=lab, teacher_prob=beta)
        episodes += col.num_worlds
        n0 = len(bufs[k])
        bufs[k].add(ro)
        rel = np.stack(lab.rec)[ro.valid]  # (K, N)
        relay[k] = np.concatenate([relay[k], rel])
        fresh.append((k, np.arange(n0, len(bufs[k]))))
    # agreement on this round's fresh events (round 0: the start's own play)
    acc_all, acc_rel, n_rel = [], [], 0
    for k, idx in fresh:
        a, n = agreement(k, idx[:4000], False)
        acc_all.append((a, n))
        ridx = idx[relay[k][idx].any(1)]
        if len(ridx):
            a, n = agreement(k, ridx, True)
            acc_rel.append((a, n))
            n_rel += n
    t1 = time.perf_counter()
    if r > 0:
        model.train()
        for s in range(steps):
            k = s % len(cols)
            idx = rng.integers(0, len(bufs[k]), 192)
            loss, _ = imitation_loss(model, bufs[k].batch(idx, model.config.n_classes, "cpu"))
            rel_events = np.flatnonzero(relay[k].any(1))
            if len(rel_events) and w > 0:
                ridx = rng.choice(rel_events, 64)
                b = bufs[k].batch(ridx, model.config.n_classes, "cpu")
                b["active"] = torch.from_numpy(relay[k][ridx])
                lr_, _ = imitation_loss(model, b)
                loss = loss + w * lr_
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), 10.0)
            opt.step()
        save_model(model, out / f"round{r}.pt")
    row = {
        "round": r,
        "beta": beta,
        "events": sum(len(b) for b in bufs),
        "relay_labels_fresh": n_rel,
        "agree_all_fresh": weighted(acc_all),
        "agree_relay_fresh": weighted(acc_rel),
        "collect_s": t1 - t0,
        "update_s": time.perf_counter() - t1,
    }
    print(json.dumps(row), flush=True)
    log.write(json.dumps(row) + "\n")
    log.flush()
