"""MAPPO on the native TorchRL env, built from TorchRL's own parts — the recipe of TorchRL's
``sota-implementations/multiagent/mappo_ippo.py`` on ``catmip_rl.adapters.torchrl_env.CatmipEnv``:

* ``TransformedEnv(CatmipEnv, float_observation_transform() + RewardSum + RewardScaling)``;
* a shared policy (a small CNN over each robot's float maps, parameters shared by all robots) as a
  ``ProbabilisticActor`` with a ``MaskedCategorical`` over the action mask;
* a centralised critic over the privileged ``"state"`` (ground truth) and each robot's own map;
* ``Collector``, ``GAE`` on the group-level keys ``("robots", "reward" | "done" | "terminated")``,
  ``ClipPPOLoss``, a ``ReplayBuffer`` with ``SamplerWithoutReplacement``.

Every env step is one decision event; busy robots take their single allowed action ("keep your goal"),
which carries no gradient. Unlike ``catmip train`` (AMAT, asynchronous GAE along each robot's own
activations, γ per tick) this is plain MAPPO with γ per event — the generic baseline a TorchRL user
would start from.

    python examples/mappo_torchrl.py                          # the `small` world for 5 minutes
    python examples/mappo_torchrl.py --world task1 --minutes 20 --frames 2000000

It prints, per iteration, the mean per-robot return and the success rate of the episodes that ended
in the batch (sampled actions, training activation, a new map every episode). Measured with the
defaults and ``--threads 1`` (the `small` world: 12×12, rescuer + explorer, horizon 80; 32 worlds × 32
events an iteration) on a 2-core machine shared with another training run, seeds 0 and 1: in the
first half minute 73 / 71 return per robot and 0.09 / 0.08 success, in the fifth minute 200 / 207 and
0.81 / 0.82 (random goals: 68 / 0.07, the Nearest planner: 212 / 0.91; table in docs/torchrl.md).
"""

from __future__ import annotations

import argparse
import math
import time

import torch
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, ReplayBuffer, SamplerWithoutReplacement
from torchrl.envs import Compose, RewardScaling, RewardSum, TransformedEnv
from torchrl.modules import MaskedCategorical, ProbabilisticActor
from torchrl.objectives import ClipPPOLoss, ValueEstimators

from catmip_rl.adapters import keys as K
from catmip_rl.adapters.torchrl_env import CatmipEnv, float_observation_transform
from catmip_rl.training.config import TRAIN_PRESETS

LOGITS = (K.ROBOTS, "logits")
EPISODE_REWARD = (K.ROBOTS, "episode_reward")


def conv_trunk(channels: int, size: int) -> tuple[nn.Module, int]:
    """(M, channels, size, size) -> (M, features): two stride-2 convolutions; returns (trunk, features)."""
    trunk = nn.Sequential(
        nn.Conv2d(channels, 16, 3, stride=2, padding=1),
        nn.ReLU(),
        nn.Conv2d(16, 32, 3, stride=2, padding=1),
        nn.ReLU(),
        nn.Flatten(),
    )
    return trunk, 32 * math.ceil(math.ceil(size / 2) / 2) ** 2


def _per_robot(module: nn.Module, x: torch.Tensor) -> torch.Tensor:
    """Apply a module over (..., C, H, W) maps with any leading dims (worlds, time, robots)."""
    return module(x.reshape(-1, *x.shape[-3:])).reshape(*x.shape[:-3], -1)


class PolicyNet(nn.Module):
    """Per-robot action logits (..., A) from the robot's float global map (..., 5 + C, H, W), local map
    (..., 4 + C, L, L) and class one-hot (..., C); one set of parameters for every robot."""

    def __init__(self, env: CatmipEnv, hidden: int = 128) -> None:
        super().__init__()
        g, l = env.observation_spec[K.GLOBAL_MAP].shape, env.observation_spec[K.LOCAL_MAP].shape
        a = env.engine.num_actions
        self.global_trunk, features = conv_trunk(g[-3], g[-1])
        inputs = features + l[-3] * l[-2] * l[-1] + env.cfg.num_classes
        self.head = nn.Sequential(
            nn.Linear(inputs, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, a)
        )

    def forward(self, global_map: torch.Tensor, local_map: torch.Tensor, agent_class: torch.Tensor):
        x = torch.cat([_per_robot(self.global_trunk, global_map), local_map.flatten(-3), agent_class], -1)
        return self.head(x)


class CentralCritic(nn.Module):
    """Per-robot values (..., N, 1) from the world's ground truth ``state`` (..., 4 + C, H, W) — shared
    by the robots — stacked on each robot's own global map (..., N, 5 + C, H, W), plus its class."""

    def __init__(self, env: CatmipEnv, hidden: int = 128) -> None:
        super().__init__()
        s, g = env.observation_spec[K.STATE].shape, env.observation_spec[K.GLOBAL_MAP].shape
        self.trunk, features = conv_trunk(s[-3] + g[-3], g[-1])
        self.head = nn.Sequential(
            nn.Linear(features + env.cfg.num_classes, hidden), nn.ReLU(), nn.Linear(hidden, 1)
        )

    def forward(self, state: torch.Tensor, global_map: torch.Tensor, agent_class: torch.Tensor):
        state = state.unsqueeze(-4).expand(*global_map.shape[:-3], *state.shape[-3:])
        x = _per_robot(self.trunk, torch.cat([state, global_map], -3))
        return self.head(torch.cat([x, agent_class], -1))


def make_env(world: str, num_worlds: int, seed: int, reward_scale: float) -> TransformedEnv:
    """The training world of a ``catmip train`` preset, with float maps, episode returns (raw rewards,
    for the log) and scaled rewards (for GAE and the critic)."""
    base = CatmipEnv(TRAIN_PRESETS[world].env_config(), num_worlds=num_worlds, seed=seed)
    return TransformedEnv(
        base,
        Compose(
            float_observation_transform(),
            RewardSum(in_keys=[K.REWARD], out_keys=[EPISODE_REWARD]),
            RewardScaling(loc=0.0, scale=reward_scale, in_keys=[K.REWARD]),
        ),
    )


def main(argv: list[str] | None = None) -> list[dict[str, float]]:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--world", default="small", choices=sorted(TRAIN_PRESETS), help="a catmip train preset's world"
    )
    ap.add_argument("--minutes", type=float, default=5.0, help="wall-clock budget")
    ap.add_argument("--frames", type=int, default=10_000_000, help="budget in env frames (worlds x events)")
    ap.add_argument("--worlds", type=int, default=32, help="worlds stepped together")
    ap.add_argument("--events", type=int, default=32, help="events per world per iteration")
    ap.add_argument("--epochs", type=int, default=4)
    ap.add_argument("--minibatch", type=int, default=256, help="frames per minibatch")
    ap.add_argument("--lr", type=float, default=3e-4)
    ap.add_argument("--gamma", type=float, default=0.99, help="discount per event")
    ap.add_argument("--reward-scale", type=float, default=0.01)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)

    env = make_env(args.world, args.worlds, args.seed, args.reward_scale)
    actor = ProbabilisticActor(
        TensorDictModule(PolicyNet(env.base_env), in_keys=list(K.OBS_KEYS), out_keys=[LOGITS]),
        in_keys={"logits": LOGITS, "mask": K.ACTION_MASK},
        out_keys=[K.ACTION],
        distribution_class=MaskedCategorical,
        return_log_prob=True,  # written to K.LOG_PROB = ("robots", "action_log_prob")
    )
    critic = TensorDictModule(
        CentralCritic(env.base_env), in_keys=[K.STATE, K.GLOBAL_MAP, K.AGENT_CLASS], out_keys=[K.VALUE]
    )
    loss_module = ClipPPOLoss(actor, critic, clip_epsilon=0.2, entropy_coeff=0.01, loss_critic_type="l2")
    loss_module.set_keys(
        reward=K.REWARD,
        action=K.ACTION,
        sample_log_prob=K.LOG_PROB,
        value=K.VALUE,
        done=K.DONE,
        terminated=K.TERMINATED,
    )
    loss_module.make_value_estimator(ValueEstimators.GAE, gamma=args.gamma, lmbda=0.95)
    gae = loss_module.value_estimator
    optim = torch.optim.Adam(loss_module.parameters(), args.lr)

    frames_per_batch = args.worlds * args.events
    collector = Collector(
        env,
        actor,
        frames_per_batch=frames_per_batch,
        total_frames=args.frames,
        auto_register_policy_transforms=False,  # a feed-forward policy: no InitTracker / primers
    )
    buffer = ReplayBuffer(
        storage=LazyTensorStorage(frames_per_batch),
        sampler=SamplerWithoutReplacement(),
        batch_size=args.minibatch,
    )

    history, start = [], time.perf_counter()
    for iteration, data in enumerate(collector):
        with torch.no_grad():
            gae(
                data,
                params=loss_module.critic_network_params,
                target_params=loss_module.target_critic_network_params,
            )
        buffer.extend(data.reshape(-1))
        for _ in range(args.epochs * max(1, frames_per_batch // args.minibatch)):
            losses = loss_module(buffer.sample())
            loss = losses["loss_objective"] + losses["loss_critic"] + losses["loss_entropy"]
            optim.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(loss_module.parameters(), 1.0)
            optim.step()
        collector.update_policy_weights_()

        done = data["next", "done"].squeeze(-1)  # (worlds, events): episodes that ended in this batch
        row = {
            "iteration": iteration,
            "frames": (iteration + 1) * frames_per_batch,
            "minutes": (time.perf_counter() - start) / 60,
            "episodes": int(done.sum()),
            "episode_reward": data["next", EPISODE_REWARD][data["next", K.DONE]].mean().item(),
            "success_rate": data["next", "terminated"].squeeze(-1)[done].float().mean().item(),
            **{k: losses[k].item() for k in ("loss_objective", "loss_critic", "loss_entropy")},
        }
        history.append(row)
        print(
            f"iter {iteration:4d}  {row['minutes']:5.1f} min  episodes {row['episodes']:4d}  "
            f"reward/robot {row['episode_reward']:7.2f}  success {row['success_rate']:.2f}  "
            f"loss π {row['loss_objective']:+.3f} V {row['loss_critic']:.3f} H {row['loss_entropy']:+.4f}"
        )
        if row["minutes"] >= args.minutes:
            break
    collector.shutdown()
    return history


if __name__ == "__main__":
    main()
