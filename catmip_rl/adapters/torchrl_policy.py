"""A TorchRL policy on the evaluation protocol: :class:`TorchRLPolicy` turns a ``TensorDictModule`` that
reads :class:`~catmip_rl.adapters.torchrl_env.CatmipEnv`'s keys into an engine-level policy
(``act(engine) -> (B, N)``), so that ``catmip eval --method NAME=py:FILE.py:FACTORY`` and
``evaluate(policy=...)`` can play it on the same maps as every other method::

    def make_policy(env_config, seed):
        actor = ...  # e.g. the ProbabilisticActor of examples/mappo_torchrl.py, weights loaded
        return TorchRLPolicy(actor, float_maps=True)

Each call builds the observation ``CatmipEnv`` would give for the engine's current event
(:func:`~catmip_rl.adapters.torchrl_env.engine_observation`), runs the module on it and reads
``("robots", "action")``. ``float_maps=True`` gives the module the maps as
:func:`~catmip_rl.adapters.torchrl_env.float_observation_transform` does (float32, ``value ×
OBS_SCALE``), for a policy trained behind that transform; AMAT's own actor reads the uint8 maps.
Actions are the distribution's mode (``deterministic=True``, the protocol's argmax) or samples.
``per_robot=True`` is for a module that maps each robot's observation on its own (no attention across
robots or worlds, as the MAPPO / IPPO CNN): it is then fed the deciding robots alone, a ``(M,)`` batch
(:func:`~catmip_rl.adapters.torchrl_env.deciding_observation`) — on Task 3 about a quarter of the rows,
the same argmax actions.
"""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from catmip_env.constants import OBS_SCALE
from catmip_env.engines.events import EventEngine
from catmip_rl.adapters import keys as K
from catmip_rl.adapters.torchrl_env import deciding_observation, engine_observation

__all__ = ["TorchRLPolicy"]


class TorchRLPolicy:
    """An engine-level policy (``level = "engine"``, window goals) from a TorchRL module."""

    level = "engine"
    goal_mode = "window"

    def __init__(
        self,
        module: TensorDictModuleBase,
        float_maps: bool = False,
        deterministic: bool = True,
        per_robot: bool = False,
        files: tuple[str, ...] = (),
    ) -> None:
        if not isinstance(module, TensorDictModuleBase):
            raise TypeError(f"TorchRLPolicy wraps a TensorDictModule, got {type(module).__name__}")
        self.module = module
        self.float_maps = float_maps
        self.deterministic = deterministic
        self.per_robot = per_robot
        self.files = tuple(files)  # the weights it was loaded from: their hashes go on the results

    def sampled(self, seed: int) -> TorchRLPolicy:
        """The same module with sampled actions (``ExplorationType.RANDOM``), torch's global generator
        seeded with ``seed``: the evaluator plays the maps again with it (the ``sampled_*`` numbers)."""
        torch.manual_seed(seed)
        return TorchRLPolicy(
            self.module, self.float_maps, deterministic=False, per_robot=self.per_robot, files=self.files
        )

    @staticmethod
    def wraps(obj) -> bool:
        """Whether ``obj`` is a TorchRL module this class turns into a policy."""
        return isinstance(obj, TensorDictModuleBase)

    def observation(self, engine: EventEngine) -> TensorDictBase:
        """What the module reads: ``CatmipEnv``'s observation of the current event (maps as float32 if
        ``float_maps``), on the module's device."""
        return self._scaled(engine_observation(engine, self._device()))

    def _device(self) -> torch.device | str:
        params = list(self.module.parameters())
        return params[0].device if params else "cpu"

    def _scaled(self, td: TensorDictBase) -> TensorDictBase:
        if self.float_maps:
            for key in (K.GLOBAL_MAP, K.LOCAL_MAP):
                td.set(key, td.get(key).to(torch.float32) * OBS_SCALE)
        return td

    @torch.no_grad()
    def act(self, engine: EventEngine):
        if self.per_robot:  # the deciding robots alone, as a (M,) batch; busy robots' entries are ignored
            active = engine.active
            actions = np.zeros(active.shape, dtype=np.int64)
            if active.any():
                actions[active] = self._actions(deciding_observation(engine, self._device()))
            return actions
        return self._actions(engine_observation(engine, self._device()))

    def _actions(self, td: TensorDictBase) -> np.ndarray:
        kind = ExplorationType.DETERMINISTIC if self.deterministic else ExplorationType.RANDOM
        with set_exploration_type(kind):
            return self.module(self._scaled(td)).get(K.ACTION).cpu().numpy()
