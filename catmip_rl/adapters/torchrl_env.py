"""A native TorchRL multi-agent env over the batched event engine, and the float-observation transform.

:class:`CatmipEnv` is the recommended TorchRL entry point (its docstring is its documentation page);
:func:`float_observation_transform` turns its uint8 maps into float32 for networks of your own.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from tensordict import NestedKey, TensorDict, TensorDictBase
from torchrl.data import Binary, Bounded, Categorical, Composite, Unbounded
from torchrl.envs import ActionMask, Compose, DTypeCastTransform, EnvBase, ObservationNorm

from catmip_env import EnvConfig, make_config
from catmip_env.constants import OBS_ONE, OBS_SCALE
from catmip_env.engines.events import EventEngine
from catmip_env.planners.proposals import Proposals
from catmip_rl.adapters import keys as K
from catmip_rl.amat.inputs import one_hot_class

__all__ = ["CatmipEnv", "engine_observation", "deciding_observation", "float_observation_transform"]

_DONE_NAMES = ("done", "terminated", "truncated")


class CatmipEnv(EnvBase):
    """CATMiP search and rescue as a batched TorchRL multi-agent env: ``B`` independent worlds, one
    step = one decision **event** in every world (each world advances to its *own* next event).

    ``CatmipEnv(preset="train", num_worlds=1, seed=0, goal_mode="window", **EnvConfig_overrides)``

    The recommended TorchRL entry point. TorchRL's ``PettingZooWrapper`` over
    ``catmip_env.envs.search_rescue_v0`` works too (it passes TorchRL's spec check), but it steps one world
    and, because the PettingZoo observation is itself a dict ``{"observation": {...}, "action_mask":
    ...}``, its keys come out double-nested: ``("robot", "observation", "observation", "global_map")``
    (group ``"robot"``; ``"agents"`` under ``MarlGroupMapType.ALL_IN_ONE_GROUP``), float32 maps and
    the active flags as float32 ``("robot", "info", "active")``.

    **Robots** — one group, ``"robots"`` (``group_map = {"robots": ["robot_0", …, "robot_{N-1}"]}``),
    of the preset's team: rescuers (2 ticks per primitive action, can rescue) and explorers (1 tick).

    **Action** ``("robots", "action")`` (B, N) int64: a goal in the robot's D×D window (``goal_mode=
    "window"``, D² actions, the centre = stay) or any cell (``"cell"``, H·W actions). Only the
    *active* robots' actions are used; a busy robot's mask allows exactly one action ("keep your
    goal"), so a masked policy can act for every robot every step.

    **Observation** (batch dims (B,) at the root, (B, N) under ``"robots"``):

    ============================  ===================  =======  ============================================
    key                           shape                dtype    meaning
    ============================  ===================  =======  ============================================
    ``("robots","global_map")``   (B, N, 5 + C, H, W)  uint8    robot's belief map (float = value × 0.25)
    ``("robots","local_map")``    (B, N, 4 + C, L, L)  uint8    the same channels around the robot
    ``("robots","agent_class")``  (B, N, C)            float32  class one-hot
    ``("robots","action_mask")``  (B, N, A)            bool     allowed actions
    ``("robots","active")``       (B, N)               bool     robots that choose a goal now
    ``("robots","neighbourhood")``  (B, N)             int64    communication component (lowest id in it)
    ``("robots","hint")``         (B, N)               int64    ``proposals``' cell for an active robot, −1
    ``"state"``                   (B, 4 + C, H, W)     float32  ground truth in {0, 1} (below)
    ``"event_ticks"``             (B, 1)               int64    ticks the last step ran (0 at reset)
    ============================  ===================  =======  ============================================

    ``"state"`` is the world's ground truth, the same array as the PettingZoo env's ``state()``:
    occupied (walls, obstacles), target, clues, explored by any robot, then one channel per class with
    that class's robot cells. It is privileged (it shows the unknown target): a centralised critic's
    input during training, never a policy's. :func:`float_observation_transform` converts the uint8 maps
    (channel layout: docs/environment.md) to float32.

    **Reward** ``("robots", "reward")`` (B, N, 1) float32: each robot's primitive rewards summed since
    the previous event — −0.05 per forward move, ``collision_penalty`` per blocked move, and to every
    robot ``100 (1 − 0.9 t/h)`` when the target is first known, ``300 (1 − 0.9 t/h)`` on success.

    **Termination**: success (a rescuer that knows the target stands next to it) terminates the world,
    ``horizon_ticks`` truncates it. ``"done"`` / ``"terminated"`` / ``"truncated"`` are (B, 1) at the root
    and repeated per robot under ``"robots"`` (B, N, 1), as in TorchRL's MARL envs, so that ``GAE`` and
    ``ClipPPOLoss`` read the group's done flags beside its reward and values. Finished worlds are reset
    through ``"_reset"`` (the root one, or ``("robots", "_reset")`` of any of its robots).

    **Arguments**: ``preset`` (a ``catmip_env.PRESETS`` name or an ``EnvConfig``), ``num_worlds`` B,
    ``seed`` (episode ``k`` of a seed always has the same map), ``goal_mode``, ``invalid_action``
    (``"raise"`` or ``"stay"``), ``gamma`` (the engine's per-tick discount of macro-action returns;
    the per-event reward above is undiscounted), the torch device, ``proposals`` (a planner whose cell
    goal for each active robot ``"hint"`` carries, :class:`~catmip_env.planners.proposals.Proposals`:
    what a cell-goal AMAT with ``AmatConfig.hint`` reads; "" none: −1 everywhere; a partial reset asks
    the planner again for every world, so under auto-reset a world's later proposals may differ from
    ``catmip eval``'s) and any ``EnvConfig`` field as a keyword.

    **Versions**: 2 — ``"neighbourhood"`` and ``"hint"``; 1 — group-level done flags, ``"state"``,
    ``group_map``; 0 — the macro-observations, mask, active flags, per-robot reward, ``event_ticks`` and
    root done flags (all unchanged since).
    """

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
        threads: int = 1,
        proposals: str = "",
        **overrides,
    ) -> None:
        cfg = make_config(preset, **overrides)
        super().__init__(device=device, batch_size=torch.Size([num_worlds]))
        self.cfg = cfg
        self.engine = EventEngine(
            cfg,
            num_worlds,
            seed,
            goal_mode=goal_mode,
            invalid_action=invalid_action,
            gamma=gamma,
            threads=threads,
        )
        self.proposals = Proposals(proposals)
        self.group_map = {K.ROBOTS: [f"robot_{i}" for i in range(self.engine.num_robots)]}
        self._make_specs()

    # -- specs ------------------------------------------------------------------------------------
    def _make_specs(self) -> None:
        eng, cfg = self.engine, self.cfg
        b, n, (h, w), c, a = eng.num_worlds, eng.num_robots, eng.shape, cfg.num_classes, eng.num_actions
        dev = self.device
        l = cfg.local_size

        def robots(**specs):
            return Composite(specs, shape=(b, n), device=dev)

        def flag(*shape):
            return Categorical(2, shape, dtype=torch.bool, device=dev)

        self.observation_spec = Composite(
            robots=robots(
                global_map=Bounded(0, OBS_ONE, (b, n, 5 + c, h, w), dtype=torch.uint8, device=dev),
                local_map=Bounded(0, OBS_ONE, (b, n, 4 + c, l, l), dtype=torch.uint8, device=dev),
                agent_class=Bounded(0.0, 1.0, (b, n, c), dtype=torch.float32, device=dev),
                action_mask=Binary(n=a, shape=(b, n, a), dtype=torch.bool, device=dev),
                active=Binary(n=n, shape=(b, n), dtype=torch.bool, device=dev),
                neighbourhood=Bounded(0, n - 1, (b, n), dtype=torch.int64, device=dev),
                hint=Bounded(-1, h * w - 1, (b, n), dtype=torch.int64, device=dev),
            ),
            state=Bounded(0.0, 1.0, (b, 4 + c, h, w), dtype=torch.float32, device=dev),
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
            robots=robots(**{name: flag(b, n, 1) for name in _DONE_NAMES}),
            **{name: flag(b, 1) for name in _DONE_NAMES},
            shape=(b,),
            device=dev,
        )

    # -- helpers ----------------------------------------------------------------------------------
    def _observation(self) -> TensorDict:
        out = engine_observation(self.engine, self.device)
        out.set(K.HINT, torch.from_numpy(self.proposals(self.engine)).to(self.device))
        self.action_spec[K.ACTION].update_mask(out.get(K.ACTION_MASK))
        return out

    def _set_done(self, out: TensorDictBase, terminated: np.ndarray, truncated: np.ndarray) -> None:
        """Write the (B,) flags as root (B, 1) and group-level (B, N, 1) done / terminated / truncated."""
        b, n = self.engine.num_worlds, self.engine.num_robots
        term = torch.from_numpy(terminated.copy()).view(b, 1).to(self.device)
        trunc = torch.from_numpy(truncated.copy()).view(b, 1).to(self.device)
        for name, value in zip(_DONE_NAMES, (term | trunc, term, trunc)):
            out.set(name, value)
            out.set((K.ROBOTS, name), value[:, None].expand(b, n, 1).clone())

    def _worlds_to_reset(self, tensordict: TensorDictBase | None) -> np.ndarray | None:
        """(B,) bool of the worlds a partial reset asks for, or None for all of them."""
        if tensordict is None:
            return None
        b = self.engine.num_worlds
        world = tensordict.get("_reset", None)
        robots = tensordict.get((K.ROBOTS, "_reset"), None)
        if world is None and robots is None:
            return None
        worlds = torch.zeros(b, dtype=torch.bool)
        if world is not None:
            worlds |= world.reshape(b).cpu()
        if robots is not None:
            worlds |= robots.reshape(b, -1).any(-1).cpu()
        return worlds.numpy()

    # -- EnvBase API --------------------------------------------------------------------------------
    def step(self, tensordict: TensorDictBase) -> TensorDictBase:
        """TorchRL's ``step``; anything but a TensorDict is a TypeError saying what it must hold."""
        if not isinstance(tensordict, TensorDictBase):
            raise TypeError(
                f"CatmipEnv.step takes a TensorDict with the actions at {K.ACTION} (num_worlds, num_robots)"
                f" int64, got {type(tensordict).__name__}"
            )
        return super().step(tensordict)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        self.engine.reset(worlds=self._worlds_to_reset(tensordict))
        out = self._observation()
        b = self.engine.num_worlds
        out.set(K.EVENT_TICKS, torch.zeros(b, 1, dtype=torch.int64, device=self.device))
        done = self.engine.state.done
        self._set_done(out, terminated=done, truncated=np.zeros_like(done))
        return out

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        actions = tensordict.get(K.ACTION).cpu().numpy()
        ev = self.engine.step(actions)
        out = self._observation()
        b = self.engine.num_worlds
        dev = self.device
        out.set(K.REWARD, torch.from_numpy(ev.rewards.astype(np.float32))[..., None].to(dev))
        out.set(K.EVENT_TICKS, torch.from_numpy(ev.event_ticks.copy()).view(b, 1).to(dev))
        self._set_done(out, terminated=ev.terminated, truncated=ev.truncated)
        return out

    def _set_seed(self, seed: int | None) -> None:
        self.engine.seed(seed)


def engine_observation(engine: EventEngine, device: str | torch.device = "cpu") -> TensorDict:
    """The observation :class:`CatmipEnv` gives for ``engine``'s current event, batch ``(B,)``: the
    ``"robots"`` group (maps, class one-hot, action mask, active) and the ground-truth ``"state"``; also
    what :class:`~catmip_rl.adapters.torchrl_policy.TorchRLPolicy` feeds a TorchRL policy, without
    ``"state"`` (a policy is given a read-only view, :class:`~catmip_rl.evaluation.user_policy.EngineView`,
    which withholds the ground truth)."""
    robots = _robot_rows(engine, None)
    if not isinstance(engine, EventEngine):  # a policy's read-only view: ground truth is withheld from it
        return TensorDict({K.ROBOTS: robots}, batch_size=(engine.num_worlds,)).to(device)
    state = torch.from_numpy(engine.world.ground_truth(None))
    return TensorDict({K.ROBOTS: robots, K.STATE: state}, batch_size=(engine.num_worlds,)).to(device)


def deciding_observation(engine: EventEngine, device: str | torch.device = "cpu") -> TensorDict:
    """The deciding robots' rows of :func:`engine_observation`, batch ``(M,)`` in ``engine.active``'s
    order, without the ground-truth ``"state"``: what a network that maps each robot on its own reads
    (:class:`~catmip_rl.adapters.torchrl_policy.TorchRLPolicy` with ``per_robot=True``), without
    copying the busy robots' maps."""
    robots = _robot_rows(engine, engine.active)
    return TensorDict({K.ROBOTS: robots}, batch_size=robots.batch_size).to(device)


def _robot_rows(engine: EventEngine, rows: np.ndarray | None) -> TensorDict:
    """The ``"robots"`` group, copied from the engine's arrays: of every robot, batch ``(B, N)``
    (``rows`` None), or of the robots of the ``(B, N)`` bool mask ``rows``, batch ``(M,)``."""
    pick = (lambda a: a.copy()) if rows is None else (lambda a: a[rows])  # a mask's index copies
    batch = (engine.num_worlds, engine.num_robots) if rows is None else (int(rows.sum()),)
    return TensorDict(
        {
            "global_map": torch.from_numpy(pick(engine.obs_global)),
            "local_map": torch.from_numpy(pick(engine.obs_local)),
            "agent_class": one_hot_class(pick(engine.state.cls), engine.cfg.num_classes),
            "action_mask": torch.from_numpy(pick(engine.masks).astype(np.bool_)),
            "active": torch.from_numpy(pick(engine.active)),
            "neighbourhood": torch.from_numpy(pick(engine.state.comp).astype(np.int64)),
        },
        batch_size=batch,
    )


def float_observation_transform(
    in_keys: Sequence[NestedKey] = (K.GLOBAL_MAP, K.LOCAL_MAP),
) -> Compose:
    """``TransformedEnv(CatmipEnv(...), float_observation_transform())``: the uint8 maps become float32
    in [0, 1] in place (``value × OBS_SCALE``, ``catmip_env.constants``: 4 → 1.0, a clue's 1 → 0.25), specs
    included — TorchRL's ``DTypeCastTransform`` then ``ObservationNorm(loc=0, scale=OBS_SCALE)`` — and
    TorchRL's ``ActionMask`` keeps the transformed env's action spec masked (a ``TransformedEnv`` holds
    its own copy of the spec, which ``CatmipEnv`` cannot update), so that its random actions
    (``rand_action``, ``check_env_specs``, a rollout without a policy) are allowed ones.

    For networks of your own (``examples/mappo_torchrl.py``). ``AmatActor`` reads the raw uint8 maps and
    scales them itself: do not put this transform in front of it.
    """
    keys = list(in_keys)
    return Compose(
        DTypeCastTransform(torch.uint8, torch.float32, in_keys=keys),
        ObservationNorm(loc=0.0, scale=OBS_SCALE, in_keys=keys),
        ActionMask(K.ACTION, K.ACTION_MASK),
    )
