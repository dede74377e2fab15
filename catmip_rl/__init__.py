"""catmip_rl: AMAT policy, asynchronous GAE and PPO training on TorchRL (arrives with issues 4-5)."""
