"""Shared constants: cell codes, belief bits, headings, primitive actions, observation layout."""

from __future__ import annotations

import numpy as np

# Ground-truth cell codes of the world grid (uint8).
FREE = 0
WALL = 1
OBSTACLE = 2
TARGET = 3
CLUE = 4

# Belief map bits (uint8 per cell, one map per robot). The target is impassable, so a known target
# cell carries both OCCUPIED and TARGET.
EXPLORED = 1
OCCUPIED = 2
CLUE_BIT = 4
TARGET_BIT = 8

# Headings and grid moves, clockwise: 0 = east (+col), 1 = south (+row), 2 = west, 3 = north, as
# (row step, column step); the one direction table (searches try moves in this order)
STEPS = ((0, 1), (1, 0), (0, -1), (-1, 0))
STEP_ROW = np.array([dr for dr, _ in STEPS], dtype=np.int64)
STEP_COL = np.array([dc for _, dc in STEPS], dtype=np.int64)

# Primitive actions (Discrete(4)).
TURN_LEFT = 0
TURN_RIGHT = 1
FORWARD = 2
STAY = 3
PRIMITIVE_ACTIONS = ("turn_left", "turn_right", "forward", "stay")

# Macro-observations are stored as uint8: float value = uint8 * OBS_SCALE, so 1.0 -> 4 and a
# clue's 0.25 -> 1.
OBS_SCALE = 0.25
OBS_ONE = 4
OBS_CLUE = 1
OBS_HALF = 2  # 0.5: a teammate remembered where it was last heard of (EnvConfig.teammate_memory)

# Channel indices of the macro-observation maps (C = number of robot classes).
CH_EXPLORED = 0
CH_OCCUPIED = 1
CH_TARGET = 2
CH_GOAL = 3
CH_CLASS0 = 4  # channels 4 ... 4 + C - 1: other robots of each class; global map adds own position


def global_channels(num_classes: int) -> int:
    """Channels of the global map: explored, occupied, target/clues, goal, C classes, own position."""
    return 5 + num_classes


def local_channels(num_classes: int) -> int:
    """Channels of the local map: explored, occupied, target/clues, goal, C classes."""
    return 4 + num_classes
