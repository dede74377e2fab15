"""AMAT's input: the macro-observation dict every caller builds from the event engine's arrays.

One function, so the training collector, the PPO batch, the imitation buffer, decentralised execution
and the TorchRL env all give the model the same thing: ``global_map`` and ``local_map`` as the engine's
uint8 arrays (float = value * ``OBS_SCALE``, scaled inside the model) and ``agent_class`` one-hot.
"""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["macro_observation", "one_hot_class"]


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
) -> dict[str, torch.Tensor]:
    """The model's ``obs`` dict from numpy arrays of any common leading shape (the arrays are shared,
    not copied, on CPU): ``global_map`` (..., 5+C, S, S), ``local_map`` (..., 4+C, L, L), class indices
    (...) → ``agent_class`` (..., C), and the communication components (...) → ``neighbourhood`` if
    given (read by the cell-goal model, ``amat.pointer``; the window model ignores it)."""
    obs = {
        "global_map": torch.from_numpy(global_map),
        "local_map": torch.from_numpy(local_map),
        "agent_class": one_hot_class(classes, num_classes),
    }
    if neighbourhood is not None:
        obs["neighbourhood"] = torch.from_numpy(np.asarray(neighbourhood, np.int64))
    return obs if device is None else {k: v.to(device) for k, v in obs.items()}
