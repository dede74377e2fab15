"""Pilot, part 3: DAgger of Nearest from fresh weights with the value head learning the returns from the start."""
import json, sys, time
from pathlib import Path
import torch
torch.set_num_threads(1)
from catmip_env.config import make_config
from catmip_rl.store.checkpoint import load_model, save_model
from catmip_rl.training.collect import Collector
from catmip_rl.training.gae import ValueNorm
from catmip_rl.training.imitation import dagger

out = Path("/root/runs/pilot3")
COMMS = [None, 4, 2]
worlds = [
    ("train", {"comm_sigma_choices": COMMS}, 48),
    ("task1", {"activation": [2, 5], "comm_sigma_choices": COMMS}, 48),
    ("task2", {"activation": [2, 5], "comm_sigma_choices": COMMS}, 48),
    ("task2", {"map_size": 26, "team": ["rescuer", "explorer", "explorer", "random"], "horizon_ticks": 450,
               "activation": [2, 5], "slam_noise": 0.05, "comm_sigma_choices": COMMS}, 32),
    ("task3", {"activation": [2, 5], "comm_sigma_choices": COMMS}, 32),
]
cols = [Collector(make_config(p, **o), n, seed=200 + k, goal_mode="cell") for k, (p, o, n) in enumerate(worlds)]
torch.manual_seed(1)
from catmip_rl.amat.model import AmatConfig
from catmip_rl.amat.pointer import make_model
model = make_model(AmatConfig(goals="cell"))
value_norm = ValueNorm()
t0 = time.time()
log = open(out / "rounds.jsonl", "a")
def on_round(row):
    row["minutes"] = (time.time() - t0) / 60
    log.write(json.dumps(row) + "\n"); log.flush()
    save_model(model, out / "student.pt", extra={"round": row["round"], "value_norm": value_norm.state_dict()})
    print(json.dumps(row), flush=True)
dagger(model, cols, "nearest", rounds=int(sys.argv[1]), steps_per_round=300, batch_events=128, lr=1e-3,
       buffer_events=200_000, seed=1, on_round=on_round, value_norm=value_norm, first_episode=10_000)
