"""Asynchronous-aware collection: one iteration = one episode in each of B worlds of the event engine.

At every step each live world sits at its own decision event; the policy runs once on the batch of
live worlds and only active robots' goals are applied. Samples (docs/design.md#samples) go into preallocated
``(T, B, ...)`` storage: the joint macro-observations of all robots, action masks, active flags,
decision order, actions, log-probs, values, and per robot the return and duration of the macro-action
that ended at that event. Episode statistics are recorded when each world finishes.

A plain loop over :class:`~catmip_env.engines.events.EventEngine`: TorchRL's generic collector spends more in
tensordict copies per step than the whole engine step costs here.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, fields

import numpy as np
import torch

from catmip_env import EnvConfig
from catmip_env.constants import global_channels, local_channels
from catmip_env.engines.episode_stats import DecisionTracker, EpisodeRecords, episode_records, training_stats
from catmip_env.engines.events import EventEngine
from catmip_env.planners.baselines import Relay
from catmip_env.planners.proposals import Proposals
from catmip_env.play import Policy
from catmip_rl.amat.critic import critic_state, state_channels
from catmip_rl.amat.inputs import macro_observation
from catmip_rl.amat.model import AMAT, decision_order

__all__ = ["Rollout", "Collector", "STEP_FIELDS", "cpu_mirror"]


@dataclass
class Rollout:
    """One iteration's samples; arrays are views into the collector's storage, rows [0, steps)."""

    global_map: np.ndarray  # (T, B, N, 5+C, H, W) uint8
    local_map: np.ndarray  # (T, B, N, 4+C, L, L) uint8
    agent_class: np.ndarray  # (T, B, N) int64 class index
    neighbourhood: np.ndarray  # (T, B, N) int64 communication component (the lowest robot id in it)
    action_mask: np.ndarray  # (T, B, N, A) bool
    active: np.ndarray  # (T, B, N) bool
    order: np.ndarray  # (T, B, N) int64
    action: np.ndarray  # (T, B, N) int64
    log_prob: np.ndarray  # (T, B, N) float32
    value: np.ndarray  # (T, B, N) float32, the value head's (normalised) output
    ma_return: np.ndarray  # (T, B, N) float64 return of the macro-action that ended at row t
    ma_ticks: np.ndarray  # (T, B, N) int64 its duration
    valid: np.ndarray  # (T, B) bool
    label: np.ndarray | None  # (T, B, N) int64 the teacher's actions (collect(labeler=...))
    label_relay: np.ndarray | None  # (T, B, N) bool the labels a relay teacher's relay rule chose
    state: np.ndarray | None  # (T, B, 5+C, H, W) uint8 the true state, for a model with critic "state"
    hint: np.ndarray  # (T, B, N) int64 the proposals a model with AmatConfig.hint reads (-1: none)
    final_return: np.ndarray  # (B, N) float64 each robot's last macro-action's return
    terminated: np.ndarray  # (B,) bool the episode ended in a rescue (its last macro-actions are trained)
    records: EpisodeRecords  # the B episodes' records (catmip_env.engines.episode_stats), stalls included
    returns: np.ndarray  # (B, N) float64 each robot's episode return
    stats: dict[str, float]  # training_stats of records and returns: what the training log shows

    @property
    def steps(self) -> int:
        return self.valid.shape[0]

    @property
    def num_samples(self) -> int:
        return int(self.valid.sum())


_PER_EPISODE = ("final_return", "terminated", "records", "returns", "stats")
# per step, stored only when asked for: a labeler's actions (and which its relay rule chose), a critic's state
_OPTIONAL = ("label", "label_relay", "state")
# the (T, B, ...) arrays of a Rollout, one row per decision event: the collector's storage
STEP_FIELDS = tuple(f.name for f in fields(Rollout) if f.name not in _PER_EPISODE + _OPTIONAL)


def cpu_mirror(model: AMAT, mirror: AMAT | None = None) -> AMAT:
    """The policy to run on the CPU: ``model`` itself when its weights live there; else ``mirror`` (a
    copy this returned before, of a model of the same config) or a new copy, on the CPU with
    ``model``'s current weights. Collection plays it, so a model trained on a GPU still acts on the CPU
    cores, beside the numpy worlds."""
    if all(p.device.type == "cpu" for p in model.parameters()):
        return model
    if mirror is None or mirror.config != model.config:
        return copy.deepcopy(model).cpu()
    mirror.load_state_dict(model.state_dict())
    return mirror


class Collector:
    """Runs B worlds of ``cfg`` for one episode each per call, with the policy on the CPU (a model
    trained on a GPU plays through its CPU copy, refreshed at every call: ``cpu_mirror``).
    ``goal_mode`` is the model's (``AmatConfig.goals``): "window" or "cell"."""

    def __init__(
        self, cfg: EnvConfig, num_worlds: int, seed: int, gamma: float = 1.0, goal_mode: str = "window"
    ) -> None:
        self.engine = EventEngine(cfg, num_worlds, seed, goal_mode=goal_mode, gamma=gamma)
        self.seed = seed
        self._mirror: AMAT | None = None  # the CPU copy of a model that lives elsewhere
        eng = self.engine
        b, n, (h, w), c = eng.num_worlds, eng.num_robots, eng.shape, cfg.num_classes
        t = cfg.horizon_ticks + 1  # every event takes >= 1 tick, so no episode has more decisions
        l = cfg.local_size
        shapes = {  # per (T, B) row: trailing shape and dtype of each STEP_FIELDS array
            "global_map": ((n, global_channels(c), h, w), np.uint8),
            "local_map": ((n, local_channels(c), l, l), np.uint8),
            "agent_class": ((n,), np.int64), "neighbourhood": ((n,), np.int64),
            "action_mask": ((n, eng.num_actions), np.bool_), "active": ((n,), np.bool_),
            "order": ((n,), np.int64), "action": ((n,), np.int64),
            "log_prob": ((n,), np.float32), "value": ((n,), np.float32), "ma_return": ((n,), np.float64),
            "ma_ticks": ((n,), np.int64), "valid": ((), np.bool_), "hint": ((n,), np.int64),
        }  # fmt: skip
        self._store = {k: np.zeros((t, b, *shapes[k][0]), shapes[k][1]) for k in STEP_FIELDS}
        self._final = np.zeros((b, n), np.float64)
        self._terminated = np.zeros(b, np.bool_)
        self._label = np.zeros((t, b, n), np.int64)
        self._relay = np.zeros((t, b, n), np.bool_)
        self._state = np.zeros((0, b, state_channels(c), h, w), np.uint8)  # grown for a state critic
        self.tracker = DecisionTracker(b, n)

    @property
    def num_worlds(self) -> int:
        """Episodes a :meth:`collect` call plays (one per world)."""
        return self.engine.num_worlds

    @torch.no_grad()
    def collect(
        self,
        model: AMAT,
        first_episode: int,
        generator: torch.Generator | None = None,
        deterministic: bool = False,
        labeler: Policy | None = None,
        teacher_prob: float = 0.0,
    ) -> Rollout:
        """One episode per world (episode indices ``first_episode + b``); returns the samples.

        ``labeler.act(engine)`` (e.g. a :class:`~catmip_env.planners.window.WindowPlanner`, or a planner
        for cell goals), if given, labels every event's active robots with its actions
        (``Rollout.label``; a relay planner's also says which labels its relay rule chose,
        ``Rollout.label_relay``); each active robot then executes the label instead of the policy's action
        with probability ``teacher_prob`` (DAgger's mixture; drawn from ``generator``). Log-probs stay
        the policy's: a rollout with ``teacher_prob > 0`` is for imitation, not for PPO. ``Rollout.hint``:
        the proposals of the model's ``AmatConfig.hint`` planner (:class:`Proposals`; -1 without one)."""
        eng, s = self.engine, self._store
        policy = cpu_mirror(model, self._mirror)
        if policy is not model:  # a CPU copy of a model on another device, refreshed by the next call
            self._mirror = policy
        b_all = eng.num_worlds
        c = eng.cfg.num_classes
        eng.reset(episode_indices=np.arange(first_episode, first_episode + b_all))
        critic = policy.state_critic
        proposals = Proposals(policy.config.hint)
        if critic is not None and not len(self._state):
            self._state = np.zeros((len(s["valid"]), *self._state.shape[1:]), np.uint8)
        self.tracker.reset(eng)
        s["valid"][:] = False
        returns = np.zeros((b_all, eng.num_robots))
        t = 0
        policy.eval()
        while True:
            live = ~eng.state.done
            if not live.any():
                break
            idx = np.flatnonzero(live)
            st = eng.state
            s["global_map"][t, idx] = eng.obs_global[idx]
            s["local_map"][t, idx] = eng.obs_local[idx]
            s["agent_class"][t, idx] = st.cls[idx]
            s["neighbourhood"][t, idx] = st.comp[idx]
            s["action_mask"][t, idx] = eng.masks[idx]
            s["active"][t, idx] = eng.active[idx]
            s["valid"][t, idx] = True
            self._label_step(t, idx, labeler)
            s["hint"][t, idx] = proposals(eng)[idx]
            obs = macro_observation(
                s["global_map"][t, idx],
                s["local_map"][t, idx],
                st.cls[idx],
                c,
                s["neighbourhood"][t, idx],
                hint=s["hint"][t, idx],
            )
            active = torch.from_numpy(s["active"][t, idx])
            mask = torch.from_numpy(s["action_mask"][t, idx])
            rep, values = policy.encode(policy.embed(obs))
            if critic is not None:  # the values from the true state (amat.critic) instead
                critic_state(eng.world, self._state[t])
                state = torch.from_numpy(self._state[t, idx])
                values = critic(state, obs["global_map"], obs["agent_class"])
            order = decision_order(active)
            actions, logp = policy.decode_autoregressive(
                rep, mask, order, active, obs["agent_class"], deterministic=deterministic, generator=generator
            )
            s["order"][t, idx] = order.numpy()
            s["action"][t, idx] = actions.numpy()
            if labeler is not None and teacher_prob > 0:  # DAgger's mixture: some execute the label
                u = torch.rand(s["action"][t, idx].shape, generator=generator).numpy()
                take = (u < teacher_prob) & s["active"][t, idx]
                s["action"][t, idx] = np.where(take, self._label[t, idx], s["action"][t, idx])
            s["log_prob"][t, idx] = logp.numpy()
            s["value"][t, idx] = values[..., 0].numpy()
            full = np.zeros((b_all, eng.num_robots), np.int64)
            full[idx] = s["action"][t, idx]
            self.tracker.before_step(eng)
            ev = eng.step(full)
            returns[idx] += ev.rewards[idx]
            done = (ev.terminated | ev.truncated)[idx]
            ended, going = idx[done], idx[~done]
            self._final[ended] = ev.ma_rewards[ended]
            self._terminated[ended] = ev.terminated[ended]
            s["ma_return"][t + 1, going] = ev.ma_rewards[going]
            s["ma_ticks"][t + 1, going] = ev.ma_ticks[going]
            t += 1
        records = episode_records(eng, self.tracker)
        return Rollout(
            **{k: v[:t] for k, v in s.items()},
            final_return=self._final.copy(),
            label=self._label[:t].copy() if labeler is not None else None,
            label_relay=self._relay[:t].copy() if isinstance(labeler, Relay) else None,
            state=self._state[:t] if critic is not None else None,
            terminated=self._terminated.copy(),
            records=records,
            returns=returns,
            stats=training_stats(records, returns, eng.cfg),
        )

    def _label_step(self, t: int, idx: np.ndarray, labeler: Policy | None) -> None:
        """Row ``t`` of the labels (and which a relay teacher's relay rule chose) for the live worlds
        ``idx``, from the engine as it stands at that event."""
        if labeler is not None:
            self._label[t, idx] = labeler.act(self.engine)[idx]
            if isinstance(labeler, Relay):
                self._relay[t, idx] = labeler.relayed[idx] & self._store["active"][t, idx]
