"""The goal actions of a decision event, checked and turned into goal cells in one pass (the engine's
only serial kernel of a step: it runs before any world moves, so that a refused action changes nothing).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def goal_cells(
    actions: np.ndarray,  # (B, N) int64 goal actions
    decides: np.ndarray,  # (B, N) bool: active robots of live worlds (the only entries read)
    masks: np.ndarray,  # (B, N, A) int8 allowed actions
    cell_mode: bool,  # action r * W + c (else a d x d window around the robot, action a = dr * d + dc)
    width: int,  # W
    window: int,  # d
    stay_action: int,  # window mode: the action "stay here"
    pos: np.ndarray,  # (B, N, 2) int64
    cells: np.ndarray,  # (B, N, 2) int64 out: goal cells (the robot's own cell for a refused action)
    bad: np.ndarray,  # (B, N) bool out: refused (out of range or masked)
) -> bool:
    """Goal cells of the deciding robots' actions; returns whether any action was refused. Entries of
    robots that do not decide are read as action 0."""
    num_actions = masks.shape[2]
    half = window // 2
    refused = False
    for b in range(actions.shape[0]):
        for i in range(actions.shape[1]):
            a = actions[b, i] if decides[b, i] else 0
            bad[b, i] = decides[b, i] and not (0 <= a < num_actions and masks[b, i, a] == 1)
            if bad[b, i]:
                refused = True
                a = pos[b, i, 0] * width + pos[b, i, 1] if cell_mode else stay_action
            if cell_mode:
                cells[b, i, 0], cells[b, i, 1] = a // width, a % width
            else:
                cells[b, i, 0] = pos[b, i, 0] + a // window - half
                cells[b, i, 1] = pos[b, i, 1] + a % window - half
    return refused
