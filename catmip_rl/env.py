"""A native TorchRL env over the batched event engine: batch size [B], one step = one decision event
in every world (each world advances to its *own* next event).

Per world and robot the tensordict carries (keys of :mod:`catmip_rl.keys`): the compact uint8
macro-observations, the action mask, the active flag, the class one-hot; after a step also the
per-event reward ``("robots", "reward")`` (B, N, 1), the ticks the step took ``event_ticks`` (B, 1) and
the done flags (B, 1). Finished worlds are reset through TorchRL's ``"_reset"`` mechanism.
"""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Binary, Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from catmip_env import EnvConfig, make_config
from catmip_env.events import EventEngine
from catmip_env.types import OBS_ONE

__all__ = ["CatmipEnv"]


class CatmipEnv(EnvBase):
    """``CatmipEnv(preset="train", num_worlds=64, seed=0, **EnvConfig_overrides)``."""

    batch_locked = True

    def __init__(
        self,
        preset: str | EnvConfig = "train",
        num_worlds: int = 1,
        seed: int = 0,
        goal_mode: str = "window",
        invalid_action: str = "raise",
        gamma: float = 1.0,
        device: str | torch.device = "cpu",
        **overrides,
    ) -> None:
        cfg = make_config(preset, **overrides)
        super().__init__(device=device, batch_size=torch.Size([num_worlds]))
        self.cfg = cfg
        self.engine = EventEngine(
            cfg, num_worlds, seed, goal_mode=goal_mode, invalid_action=invalid_action, gamma=gamma
        )
        self._make_specs()

    # -- specs ------------------------------------------------------------------------------------
    def _make_specs(self) -> None:
        eng, cfg = self.engine, self.cfg
        b, n, (h, w), c, a = eng.num_worlds, eng.num_robots, eng.shape, cfg.num_classes, eng.num_actions
        dev = self.device
        l = cfg.local_size

        def robots(**specs):
            return Composite(specs, shape=(b, n), device=dev)

        self.observation_spec = Composite(
            robots=robots(
                global_map=Bounded(0, OBS_ONE, (b, n, 5 + c, h, w), dtype=torch.uint8, device=dev),
                local_map=Bounded(0, OBS_ONE, (b, n, 4 + c, l, l), dtype=torch.uint8, device=dev),
                agent_class=Bounded(0.0, 1.0, (b, n, c), dtype=torch.float32, device=dev),
                action_mask=Binary(n=a, shape=(b, n, a), dtype=torch.bool, device=dev),
                active=Binary(n=n, shape=(b, n), dtype=torch.bool, device=dev),
            ),
            event_ticks=Unbounded((b, 1), dtype=torch.int64, device=dev),
            shape=(b,),
            device=dev,
        )
        self.action_spec = Composite(
            robots=robots(action=Categorical(a, (b, n), dtype=torch.int64, device=dev)),
            shape=(b,),
            device=dev,
        )
        self.reward_spec = Composite(
            robots=robots(reward=Unbounded((b, n, 1), dtype=torch.float32, device=dev)),
            shape=(b,),
            device=dev,
        )
        self.done_spec = Composite(
            done=Categorical(2, (b, 1), dtype=torch.bool, device=dev),
            terminated=Categorical(2, (b, 1), dtype=torch.bool, device=dev),
            truncated=Categorical(2, (b, 1), dtype=torch.bool, device=dev),
            shape=(b,),
            device=dev,
        )

    # -- helpers ----------------------------------------------------------------------------------
    def _observation(self) -> TensorDict:
        eng = self.engine
        st = eng.state
        c = self.cfg.num_classes
        dev = self.device
        mask = torch.from_numpy(eng.masks.astype(np.bool_))
        self.action_spec["robots", "action"].update_mask(mask.to(dev))
        robots = TensorDict(
            {
                "global_map": torch.from_numpy(eng.obs_global.copy()),
                "local_map": torch.from_numpy(eng.obs_local.copy()),
                "agent_class": torch.nn.functional.one_hot(torch.from_numpy(st.cls), c).float(),
                "action_mask": mask,
                "active": torch.from_numpy(eng.active.copy()),
            },
            batch_size=(eng.num_worlds, eng.num_robots),
        )
        return TensorDict({"robots": robots}, batch_size=self.batch_size).to(dev)

    # -- EnvBase API --------------------------------------------------------------------------------
    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        worlds = None
        if tensordict is not None and "_reset" in tensordict.keys():
            worlds = tensordict.get("_reset").reshape(-1).cpu().numpy()
        self.engine.reset(worlds=worlds)
        out = self._observation()
        b = self.engine.num_worlds
        done = torch.from_numpy(self.engine.state.done.copy()).view(b, 1).to(self.device)
        out.set("event_ticks", torch.zeros(b, 1, dtype=torch.int64, device=self.device))
        out.set("done", done)
        out.set("terminated", done.clone())
        out.set("truncated", torch.zeros_like(done))
        return out

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        actions = tensordict.get(("robots", "action")).cpu().numpy()
        ev = self.engine.step(actions)
        out = self._observation()
        b = self.engine.num_worlds
        dev = self.device
        out.set(("robots", "reward"), torch.from_numpy(ev.rewards.astype(np.float32))[..., None].to(dev))
        out.set("event_ticks", torch.from_numpy(ev.event_ticks.copy()).view(b, 1).to(dev))
        term = torch.from_numpy(ev.terminated.copy()).view(b, 1).to(dev)
        trunc = torch.from_numpy(ev.truncated.copy()).view(b, 1).to(dev)
        out.set("terminated", term)
        out.set("truncated", trunc)
        out.set("done", term | trunc)
        return out

    def _set_seed(self, seed: int | None) -> None:
        self.engine.seed(seed)
