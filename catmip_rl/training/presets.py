"""Training presets: the recipes ``catmip train --preset NAME`` runs, each a TrainConfig."""

from __future__ import annotations

from typing import Any

from catmip_rl.training.config import TrainConfig

__all__ = ["TRAIN_PRESETS", "FINE_TUNING_PRESETS", "make_train_config"]

# the Task-1 world (15x15, rescuer + explorer) with training activation (2, 5), d = 64; step control:
# at most 6 epochs x 4 minibatches, stopped once a minibatch's approx-KL exceeds 0.01 (docs/training.md,
# "Step control"); ~2 s an iteration on one thread (~1 s once a warm start makes the KL target stop it)
# what the Task-1 experiments found (docs/notes/training-experiments.md): step control, and the warm start
_STEP_CONTROL = {"epochs": 6, "minibatches": 4, "clip": 0.1, "target_kl": 0.01}
_WARM_START = {
    "warm_start": "nearest",
    "warm_start_rounds": 12,
    "warm_start_steps": 300,
    "value_warmup_iterations": 5,
}
_EVAL_64 = {"eval_episodes": 64, "eval_seed": 2025}
# the paper's recipe: TrainConfig's defaults; every preset is it with some fields changed (flat names)
_PAPER = TrainConfig()
_COMMS = [None, 4, 2]  # communication drawn per episode: full, sigma = 4, sigma = 2

# the mixture of worlds the general models train on, taking turns: the paper's, Tasks 1-3's teams and map
# sizes, and a 26x26 four-robot world with SLAM noise, each with training activation and its communication
# range drawn per episode (full, 4, 2); the large worlds collect fewer episodes an iteration
_MIXTURE = [
    {"preset": "train", "comm_sigma_choices": _COMMS},
    {"preset": "task1", "activation": [2, 5], "comm_sigma_choices": _COMMS},
    {"preset": "task2", "activation": [2, 5], "comm_sigma_choices": _COMMS},
    {
        "preset": "task2",
        "map_size": 26,
        "team": ["rescuer", "explorer", "explorer", "random"],
        "horizon_ticks": 450,
        "activation": [2, 5],
        "slam_noise": 0.05,
        "comm_sigma_choices": _COMMS,
        "num_worlds": 32,
    },
    {"preset": "task3", "activation": [2, 5], "comm_sigma_choices": _COMMS, "num_worlds": 16},
]

# PPO on the mixture, evaluated on Task 3 (64 maps of the evaluation seed)
_ON_THE_MIXTURE = _PAPER.replace(
    env_preset="task3",
    env_overrides={"activation": [2, 5]},
    worlds=_MIXTURE,
    precision="auto",
    num_worlds=64,
    iterations=100_000,
    lr=1e-4,
    eval_every=25,
    checkpoint_every=10,
    **_STEP_CONTROL,
    **_EVAL_64,
)

_TASK1 = _PAPER.replace(
    env_preset="task1",
    env_overrides={"activation": [2, 5]},
    amat={"embed_dim": 64},
    num_worlds=64,
    iterations=600,
    lr=3e-4,
    eval_every=10,
    checkpoint_every=20,
    **_STEP_CONTROL,
    **_EVAL_64,
)

TRAIN_PRESETS: dict[str, TrainConfig] = {
    # the paper's recipe; on CPU the update's gradients come from two single-threaded processes
    "paper": _PAPER.replace(update_processes=2),
    "paper-sync": _PAPER.replace(env_overrides={"synchronous": True}, update_processes=2),
    "paper-smallma": _PAPER.replace(env_overrides={"window": 5}, amat={"window": 5}, update_processes=2),
    # minutes on 2 cores: a 12x12 map, two robots, d = 64, more and larger PPO steps than the paper;
    # the slow learning test trains it and checks it beats the random policy clearly
    "small": _PAPER.replace(
        env_overrides={"map_size": 12, "team": ["rescuer", "explorer"], "horizon_ticks": 80},
        amat={"embed_dim": 64},
        num_worlds=64,
        iterations=100,
        epochs=6,
        minibatches=4,
        lr=5e-4,
        clip=0.1,
        eval_every=20,
        checkpoint_every=20,
    ),
    "task1": _TASK1,
    # task1 after an imitation warm start: DAgger against the window-projected Nearest planner, then
    # PPO with a value warm-up (the README demo; the shipped amat_task1.pt is this recipe with a 40-minute
    # budget); iterations stop early on the KL target, ~1 s each on one thread
    "task1-warm": _TASK1.replace(iterations=2000, **_WARM_START),
    # the paper's training world and AMAT (Table 2, d = 192) with the Task-1 findings: an imitation
    # warm start, then PPO under step control (docs/training.md); to ship as amat_paper.pt
    "paper-warm": _PAPER.replace(
        precision="auto",  # bf16 where it measures faster: 1.6x for d = 192 on AVX-512-BF16
        num_worlds=64,
        iterations=3000,
        lr=2e-4,
        eval_every=25,
        checkpoint_every=10,
        **_STEP_CONTROL,
        **_WARM_START,
        **_EVAL_64,
    ),
    # one model for every team and map size (amat_general.pt): cell goals with a pointer head
    # (amat.pointer), DAgger of Nearest in the same action space over the mixture (16 rounds, ~4,000
    # episodes), then PPO on it with communication drawn per episode and SLAM noise in one world
    "general": _ON_THE_MIXTURE.replace(
        amat={"goals": "cell"},
        warm_start="nearest",
        warm_start_rounds=16,
        warm_start_steps=300,
        warm_start_batch=128,
        warm_start_lr=1e-3,
        warm_start_value=True,  # the imitation alone leaves no critic to start PPO with
        value_warmup_iterations=20,  # four value-only turns of each world: imitation trains no value head
        entropy_coef=0.001,  # a sharp imitated policy over hundreds of cells: a tenth of the paper's bonus
    ),
    # a minute-scale smoke run: a small map, two robots, a small AMAT
    "tiny": _PAPER.replace(
        env_overrides={"map_size": 12, "team": ["rescuer", "explorer"], "horizon_ticks": 60},
        amat={"embed_dim": 32},
        num_worlds=8,
        iterations=2,
        epochs=2,
        eval_every=1,
        eval_episodes=4,
        checkpoint_every=1,
    ),
}


# amat_paper.pt's recipe (paper-warm) for the paper's two other systems (Figs. 5 and 11) with its compute:
# 5,604 PPO iterations after the warm start, amat_paper.pt's count, the LR decaying linearly over them
_PAPER_WARM_5604 = TRAIN_PRESETS["paper-warm"].replace(iterations=5604)
TRAIN_PRESETS["paper-warm-sync"] = _PAPER_WARM_5604.replace(env_overrides={"synchronous": True})
TRAIN_PRESETS["paper-warm-smallma"] = _PAPER_WARM_5604.replace(
    env_overrides={"window": 5}, amat={"window": 5}
)

# the chain that trained the memory model (run-records/general-memory/amat_general.pt; the records
# general-dagger-rrt, general-relay, general-relay-noise): each stage starts from the one before (init_from)
# 1. DAgger of RRT in its own action space over the mixture, from a Nearest-imitating `general` student
TRAIN_PRESETS["general-rrt"] = TRAIN_PRESETS["general"].replace(
    amat={"goals": "cell", "cell_mask": "reachable"},
    warm_start="rrt",
    warm_start_rounds=8,
    warm_start_lr=3e-4,
)
# 2. the teammate memory in the observation: DAgger of rrt-relay, then PPO anchored to it
TRAIN_PRESETS["general-relay"] = TRAIN_PRESETS["general-rrt"].replace(
    amat={"goals": "cell", "cell_mask": "reachable", "teammate_memory": True},
    warm_start="rrt-relay",
    anchor="rrt-relay",
    anchor_coef=0.2,
    lr=5e-5,
)
# 3. the same anchored PPO with a Task-2 world under 5 % SLAM noise added to the mixture
_NOISY_TASK2 = {**_MIXTURE[2], "slam_noise": 0.05}  # the mixture's Task-2 world, under noise
TRAIN_PRESETS["general-relay-noise"] = TRAIN_PRESETS["general-relay"].replace(
    warm_start="", worlds=[*_MIXTURE, _NOISY_TASK2], value_warmup_iterations=6
)
# amat_general.pt's last stage, from the memory model's weights (init_from; the new weights start at zero,
# the same function): the model reads the coordinated planner rrt-relay-coord's goal for each deciding robot
# (AmatConfig.hint: one more per-cell input and a logit bonus), and that planner is also its teacher and its
# anchor; a short DAgger of it (4 rounds of 32 episodes a world) over the mixture with a Task-2 and a Task-3
# world under 5 % SLAM noise added, then the anchored PPO of general-relay-noise with the anchor at a quarter
# of its weight. Its DAgger and iteration 0 are amat_general.pt (run-records/general-coord, --iterations 1)
_NOISY_TASK3 = {**_MIXTURE[4], "slam_noise": 0.05}  # the mixture's Task-3 world, under noise
_COORD = "rrt-relay-coord"
TRAIN_PRESETS["general-coord"] = TRAIN_PRESETS["general-relay-noise"].replace(
    amat={"goals": "cell", "cell_mask": "reachable", "teammate_memory": True, "hint": _COORD},
    worlds=[*_MIXTURE, _NOISY_TASK2, _NOISY_TASK3],
    value_warmup_iterations=7,
    warm_start=_COORD,
    warm_start_rounds=4,
    warm_start_steps=150,
    warm_start_worlds=32,
    warm_start_lr=3e-4,
    anchor=_COORD,
    anchor_coef=0.05,
)

#: presets that fine-tune a trained model: a new run of one needs ``init_from`` (``catmip train`` refuses it
#: without; from fresh weights they would run one stage of amat_general.pt's chain, skipping those before)
FINE_TUNING_PRESETS = ("general-rrt", "general-relay", "general-relay-noise", "general-coord")


def make_train_config(preset: str = "paper", **overrides: Any) -> TrainConfig:
    if preset not in TRAIN_PRESETS:
        raise ValueError(f"unknown training preset {preset!r}; known: {sorted(TRAIN_PRESETS)}")
    return TRAIN_PRESETS[preset].replace(**overrides) if overrides else TRAIN_PRESETS[preset]
