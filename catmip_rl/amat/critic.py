"""A centralised critic for AMAT's PPO (``AmatConfig.critic = "state"``): each robot's value from the
world's true state beside the robot's own map, as MAPPO's critic has it. The policy is untouched: it
plays from what a robot knows, and play never reads the critic.

The paper's critic is a value head on the encoder's tokens, which see only the robots of a
neighbourhood and what they know. Where news must be carried to a rescuer that has not heard of the
target, the return depends on things no robot of the neighbourhood knows (where the target and the
other rescuers are), so those values are noisy and so are the advantages PPO learns from
(docs/notes/general-model.md). This critic sees them.

State (the collector's ``state``, per world): :func:`state_channels` uint8 planes in {0, 1}: the
env's ground truth (occupied, target, clues, explored by anyone, one plane per robot class with its
robots' cells) and the cells of the robots that know where the target is. Per robot it is stacked on
the robot's own global map (``global_map``, uint8, float = value * OBS_SCALE).

Cost: the first convolution is linear in its input, so its state part is computed once per world and
added to each robot's own part, and only the robots the loss trains are scored (``rows``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from catmip_env.constants import global_channels
from catmip_rl.amat.layers import as_float

if TYPE_CHECKING:
    from catmip_env.engines.world import BatchedWorld

__all__ = ["StateCritic", "state_channels", "critic_state"]


def state_channels(num_classes: int) -> int:
    """Planes of the critic's state: the ground truth's 4 + C and the robots that know the target."""
    return 5 + num_classes


def critic_state(world: BatchedWorld, out: np.ndarray | None = None) -> np.ndarray:
    """(B, 5 + C, H, W) uint8 in {0, 1}: ``world.ground_truth`` of every world and a plane with the cells
    of the robots that know the target (``world.knows_target``); written into ``out`` if given."""
    truth = world.ground_truth(None)  # (B, 4 + C, H, W) float32 in {0, 1}
    b, c = truth.shape[:2]
    if out is None:
        out = np.empty((b, c + 1, *truth.shape[2:]), np.uint8)
    out[:, :c] = truth
    out[:, c] = 0
    st = world.state
    wb, robot = np.nonzero(world.knows_target())
    out[wb, c, st.pos[wb, robot, 0], st.pos[wb, robot, 1]] = 1
    return out


class StateCritic(nn.Module):
    """Values (K, 1) of K robots: a 3×3 convolution of (state, own map), a 2×2 max pool, a second 3×3
    convolution, max-pooled to ``pool`` × ``pool`` (any map size), then an MLP with the robot's class."""

    def __init__(self, num_classes: int, width: int = 32, pool: int = 4, hidden: int = 128) -> None:
        super().__init__()
        self.state_planes = state_channels(num_classes)
        self.conv1 = nn.Conv2d(self.state_planes + global_channels(num_classes), width // 2, 3, padding=1)
        self.conv2 = nn.Conv2d(width // 2, width, 3, padding=1)
        self.pool = pool
        self.fc1 = nn.Linear(width * pool * pool + num_classes, hidden)
        self.fc2 = nn.Linear(hidden, 1)
        for m in (self.conv1, self.conv2, self.fc1):
            nn.init.orthogonal_(m.weight.view(m.weight.shape[0], -1), gain=2**0.5)
            nn.init.zeros_(m.bias)
        nn.init.orthogonal_(self.fc2.weight, gain=1.0)
        nn.init.zeros_(self.fc2.bias)

    def forward(
        self,
        state: torch.Tensor,
        global_map: torch.Tensor,
        agent_class: torch.Tensor,
        rows: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """``state`` (M, 5 + C, H, W) uint8, ``global_map`` (M, N, 5 + C, H, W) uint8 (scaled by
        OBS_SCALE) or float, ``agent_class`` (M, N, C); ``rows`` (M, N) bool: the robots to score (all
        if None). Returns (K, 1) float values of the selected robots in row-major order, K = rows.sum()
        (or (M, N, 1) for all)."""
        m, n = global_map.shape[:2]
        select = torch.ones(m, n, dtype=torch.bool, device=global_map.device) if rows is None else rows
        world, robot = select.nonzero(as_tuple=True)
        w = self.conv1.weight
        # the state's part of the first convolution, once a world: (M, w/2, H, W)
        shared = F.conv2d(state.float(), w[:, : self.state_planes], self.conv1.bias, padding=1)
        own = as_float(global_map[world, robot])  # (K, 5 + C, H, W)
        x = F.relu(shared[world] + F.conv2d(own, w[:, self.state_planes :], padding=1))  # (K, w/2, H, W)
        x = F.relu(self.conv2(F.max_pool2d(x, 2, ceil_mode=True)))  # (K, w, H/2, W/2)
        x = F.adaptive_max_pool2d(x, self.pool).flatten(1)  # (K, w * pool * pool)
        x = F.relu(self.fc1(torch.cat([x, agent_class[world, robot].to(x.dtype)], -1)))  # (K, hidden)
        values = self.fc2(x)  # (K, 1)
        return values if rows is not None else values.view(m, n, 1)
