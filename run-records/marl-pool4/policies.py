"""The size-agnostic MAPPO and IPPO runs of this folder as ``catmip eval`` factories, one per algorithm
and training seed, each playing a world with the weights trained for its map size: Task 1's (15×15)
run, Task 2's (20×20, also the paper's training world) and Task 3's (32×32). A world of another size is
not one of theirs (``WorldNotSupported``: ``bench paper`` leaves it out of that panel).

    catmip bench suite --method "MAPPO=py:run-records/marl-pool4/policies.py:mappo_s0,\\
        py:run-records/marl-pool4/policies.py:mappo_s1,py:run-records/marl-pool4/policies.py:mappo_s2"
"""

from functools import partial
from pathlib import Path

from catmip_env.play import WorldNotSupported
from catmip_rl.adapters.torchrl_marl import load_policy

HERE = Path(__file__).parent
TASK_BY_SIZE = {15: "task1", 20: "task2", 32: "task3"}


def by_map_size(algo: str, seed: int, env_config, eval_seed: int):
    """``algo``'s run of training seed ``seed`` trained on the task of this world's map size."""
    size = env_config.map_size
    task = TASK_BY_SIZE.get(size)
    if task is None:
        raise WorldNotSupported(f"no {algo} run is trained for {size}x{size} maps")
    return load_policy(HERE / f"{algo}-{task}-s{seed}" / "policy.pt", env_config)


mappo_s0, mappo_s1, mappo_s2 = (partial(by_map_size, "mappo", s) for s in range(3))
ippo_s0, ippo_s1, ippo_s2 = (partial(by_map_size, "ippo", s) for s in range(3))
