"""RRT arm: DAgger of RRT, from the pilot student, (cell goals, no projection) into the cell-goal AMAT over the mixture."""
import json, sys, time
from pathlib import Path
import numpy as np, torch
torch.set_num_threads(int(sys.argv[1]) if len(sys.argv) > 1 else 1)
from catmip_env.config import make_config
from catmip_rl.amat.model import AmatConfig
from catmip_rl.amat.pointer import make_model
from catmip_rl.checkpoint import save_model
from catmip_rl.training.collect import Collector
from catmip_rl.training.imitation import dagger

out = Path("/root/runs/rrt-arm"); out.mkdir(exist_ok=True)
COMMS = [None, 4, 2]
worlds = [  # (preset, overrides, episodes per round)
    ("train", {"comm_sigma_choices": COMMS}, 48),
    ("task1", {"activation": [2, 5], "comm_sigma_choices": COMMS}, 48),
    ("task2", {"activation": [2, 5], "comm_sigma_choices": COMMS}, 48),
    ("task2", {"map_size": 26, "team": ["rescuer", "explorer", "explorer", "random"], "horizon_ticks": 450,
               "activation": [2, 5], "slam_noise": 0.05, "comm_sigma_choices": COMMS}, 32),
    ("task3", {"activation": [2, 5], "comm_sigma_choices": COMMS}, 32),
]
cols = [Collector(make_config(p, **o), n, seed=100 + k, goal_mode="cell") for k, (p, o, n) in enumerate(worlds)]
torch.manual_seed(0)
from catmip_rl.checkpoint import load_model
model = load_model("/work/main/run-records/general-pilot/student.pt")
t0 = time.time()
log = open(out / "rounds.jsonl", "a")
def on_round(row):
    row["minutes"] = (time.time() - t0) / 60
    log.write(json.dumps(row) + "\n"); log.flush()
    save_model(model, out / f"student.pt", extra={"round": row["round"]})
    print(json.dumps(row), flush=True)
rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 16
dagger(model, cols, "rrt", rounds=rounds, steps_per_round=300, batch_events=128, lr=3e-4,
       buffer_events=200_000, seed=0, on_round=on_round)
