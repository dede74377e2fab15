"""AMAT's input: the macro-observation dict every caller builds from the event engine's arrays.

One function, so the training collector, the PPO batch, the imitation buffer, decentralised execution
and the TorchRL env all give the model the same thing: ``global_map`` and ``local_map`` as the engine's
uint8 arrays (float = value * ``OBS_SCALE``, scaled inside the model) and ``agent_class`` one-hot.
"""

from __future__ import annotations

import numpy as np
import torch

from catmip_env.constants import CH_EXPLORED, CH_OCCUPIED, OBS_ONE

__all__ = ["clean_occupancy", "macro_observation", "one_hot_class"]


def one_hot_class(classes: np.ndarray | torch.Tensor, num_classes: int) -> torch.Tensor:
    """Class indices (any shape, int64) as a float one-hot tensor with a trailing ``num_classes`` axis."""
    if isinstance(classes, np.ndarray):
        classes = torch.from_numpy(classes)
    return torch.nn.functional.one_hot(classes, num_classes).float()


def macro_observation(
    global_map: np.ndarray,
    local_map: np.ndarray,
    classes: np.ndarray,
    num_classes: int,
    neighbourhood: np.ndarray | None = None,
    device: torch.device | str | None = None,
    hint: np.ndarray | None = None,
) -> dict[str, torch.Tensor]:
    """The model's ``obs`` dict from numpy arrays of any common leading shape (the arrays are shared,
    not copied, on CPU): ``global_map`` (..., 5+C, S, S), ``local_map`` (..., 4+C, L, L), class indices
    (...) → ``agent_class`` (..., C), and the communication components (...) → ``neighbourhood`` if
    given (read by the cell-goal model, ``amat.pointer``; the window model ignores it), and a hint
    planner's cells (...) → ``hint`` if given (``AmatConfig.hint``; -1: none)."""
    obs = {
        "global_map": torch.from_numpy(global_map),
        "local_map": torch.from_numpy(local_map),
        "agent_class": one_hot_class(classes, num_classes),
    }
    if neighbourhood is not None:
        obs["neighbourhood"] = torch.from_numpy(np.asarray(neighbourhood, np.int64))
    if hint is not None:
        obs["hint"] = torch.from_numpy(np.asarray(hint, np.int64))
    return obs if device is None else {k: v.to(device) for k, v in obs.items()}


def clean_occupancy(
    global_map: np.ndarray,  # (B, N, 5+C, H, W) uint8
    local_map: np.ndarray,  # (B, N, 4+C, L, L) uint8
    masks: np.ndarray,  # (B, N, H * W) the engine's cell-goal masks
    pos: np.ndarray,  # (B, N, 2)
    comp: np.ndarray,  # (B, N) communication components
    active: np.ndarray,  # (B, N) bool
) -> tuple[np.ndarray, np.ndarray]:
    """Copies of the maps where each active robot's occupied channel is read from its cell-goal mask
    instead of the noisy channel: an explored cell is occupied when the mask does not allow it (the
    engine computes masks from the clean belief, as the planners choose their goals), except where a
    teammate of its neighbourhood stands (the mask's rule). Without SLAM noise the copies equal the
    inputs; busy robots keep their maps (a busy robot's mask allows only its goal)."""
    g, loc = global_map.copy(), local_map.copy()
    h, w = g.shape[-2:]
    half = loc.shape[-1] // 2
    for b, i in zip(*np.nonzero(active), strict=True):
        allowed = masks[b, i].reshape(h, w).astype(bool)
        mates = np.flatnonzero((comp[b] == comp[b, i]) & (np.arange(comp.shape[1]) != i))
        allowed[pos[b, mates, 0], pos[b, mates, 1]] = True
        occupied = np.where((g[b, i, CH_EXPLORED] >= OBS_ONE) & ~allowed, OBS_ONE, 0).astype(g.dtype)
        g[b, i, CH_OCCUPIED] = occupied
        # the local window: the same cells (outside the map it reads occupied, as it did)
        r0, c0 = pos[b, i, 0] - half, pos[b, i, 1] - half
        rs, cs = slice(max(r0, 0), min(r0 + 2 * half + 1, h)), slice(max(c0, 0), min(c0 + 2 * half + 1, w))
        loc[b, i, CH_OCCUPIED, rs.start - r0 : rs.stop - r0, cs.start - c0 : cs.stop - c0] = occupied[rs, cs]
    return g, loc
