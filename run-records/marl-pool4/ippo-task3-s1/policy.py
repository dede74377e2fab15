"""The policy trained in this folder, as a ``catmip eval`` factory:

    catmip eval --task TASK --method NAME=py:run-records/marl-pool4/ippo-task3-s1/policy.py:make_policy --out OUT
"""

from pathlib import Path

from catmip_rl.adapters.torchrl_marl import load_policy


def make_policy(env_config, seed):
    return load_policy(Path(__file__).with_name("policy.pt"), env_config)
