"""Tensordict keys shared by the TorchRL env, the actor, the collector and the loss — one place.

Per-robot entries live under the ``"robots"`` group with batch dims ``(B, N)``; world-level entries
(``"state"``, ``"event_ticks"``, the root ``"done"`` flags) have batch dim ``(B,)``.
"""

from __future__ import annotations

ROBOTS = "robots"
GLOBAL_MAP = (ROBOTS, "global_map")  # (B, N, 5 + C, S, S) uint8, float = x * 0.25
LOCAL_MAP = (ROBOTS, "local_map")  # (B, N, 4 + C, L, L) uint8
AGENT_CLASS = (ROBOTS, "agent_class")  # (B, N, C) float one-hot
ACTION_MASK = (ROBOTS, "action_mask")  # (B, N, A) bool, True = allowed
ACTIVE = (ROBOTS, "active")  # (B, N) bool, robots that decide now
NEIGHBOURHOOD = (ROBOTS, "neighbourhood")  # (B, N) long, communication component (lowest robot id in it)
HINT = (ROBOTS, "hint")  # (B, N) long, a planner's proposed cell (CatmipEnv(proposals=...)), -1 none
PADDING = (ROBOTS, "padding")  # (B, N) bool, padding tokens (teams of different size)
ACTION = (ROBOTS, "action")  # (B, N) long
LOG_PROB = (ROBOTS, "action_log_prob")  # (B, N) float, 0 for busy robots
VALUE = (ROBOTS, "state_value")  # (B, N, 1) float
ORDER = (ROBOTS, "order")  # (B, N) long, robot index at each decision position
REWARD = (ROBOTS, "reward")  # (B, N, 1) float, each robot's reward since the previous event
# group-level copies of the world's root "done" / "terminated" / "truncated" (B, 1), as TorchRL's MARL
# envs carry them: GAE and ClipPPOLoss read them beside the group's reward and value
DONE = (ROBOTS, "done")  # (B, N, 1) bool
TERMINATED = (ROBOTS, "terminated")  # (B, N, 1) bool
TRUNCATED = (ROBOTS, "truncated")  # (B, N, 1) bool
STATE = "state"  # (B, 4 + C, S, S) float32 in {0, 1}: ground truth, the centralised critic's input
EVENT_TICKS = "event_ticks"  # (B, 1) long, ticks the last step ran

OBS_KEYS = (GLOBAL_MAP, LOCAL_MAP, AGENT_CLASS)  # every robot's observation
AMAT_KEYS = (*OBS_KEYS, NEIGHBOURHOOD, HINT)  # what AMAT reads (a window model: the first three)
