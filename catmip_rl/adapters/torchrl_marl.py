"""Learned MARL baselines (MAPPO, IPPO) from TorchRL's parts: networks, the asynchronous advantage, files.

``examples/mappo_torchrl.py`` is the training loop (TorchRL's ``Collector``, ``ClipPPOLoss``,
``ReplayBuffer``); this module holds what that loop and the evaluation share:

* :class:`PolicyNet` -- per-robot goal logits from the robot's own float maps and class; one set of
  parameters for every robot, in a ``ProbabilisticActor`` with a ``MaskedCategorical``
  (:func:`make_actor`);
* :class:`Critic` -- MAPPO's centralised critic (the world's ground-truth ``state`` beside the robot's
  own map) or IPPO's decentralised one (the robot's own maps only);
* :func:`decision_samples` -- the asynchronous advantage. TorchRL 0.14's GAE
  (``vec_generalized_advantage_estimate``) takes a per-step discount tensor, so ``gamma ** ticks``
  between decisions is native; it has no per-agent activity mask. What is added here: each robot's
  own decisions are gathered from the collector's batch into a time axis of their own (its rewards
  between two decisions summed with the per-tick discount), TorchRL's GAE runs on those sequences, and
  the decisions come back as flat per-robot samples for ``ClipPPOLoss``. A macro-action cut by the
  horizon or by the end of the batch is unfinished: it is not trained on, and the decision before it
  bootstraps from its value;
* :func:`save_policy` / :func:`load_policy` -- the trained actor as weights + config, and a
  ``policy.py`` beside them whose ``make_policy`` is a ``catmip eval --method py:...`` factory.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.modules import MaskedCategorical, ProbabilisticActor
from torchrl.objectives.value.functional import vec_generalized_advantage_estimate

from catmip_env.config import EnvConfig
from catmip_env.play import WorldNotSupported
from catmip_env.runtime.files import atomic_path
from catmip_rl.adapters import keys as K
from catmip_rl.adapters.torchrl_policy import TorchRLPolicy
from catmip_rl.store.files import atomic_write_text

__all__ = ["ALGOS", "PolicyNet", "Critic", "make_actor", "decision_samples", "save_policy", "load_policy"]

ALGOS = ("mappo", "ippo")
LOGITS = (K.ROBOTS, "logits")
ADVANTAGE = (K.ROBOTS, "advantage")
VALUE_TARGET = (K.ROBOTS, "value_target")
FORMAT = "catmip-torchrl-marl-v1"


def conv_trunk(channels: int, size: int | None, pool: int = 0) -> tuple[nn.Module, int]:
    """(M, channels, S, S) -> (M, features): two stride-2 convolutions, then either flattened (``pool``
    0: the features depend on the map side ``size``, so the network plays that size only) or max-pooled
    to ``pool x pool`` (any map size: the size-agnostic baselines); returns (trunk, features)."""
    layers = [
        nn.Conv2d(channels, 16, 3, stride=2, padding=1),
        nn.ReLU(),
        nn.Conv2d(16, 32, 3, stride=2, padding=1),
        nn.ReLU(),
    ]
    if pool:
        return nn.Sequential(*layers, nn.AdaptiveMaxPool2d(pool), nn.Flatten()), 32 * pool * pool
    return nn.Sequential(*layers, nn.Flatten()), 32 * math.ceil(math.ceil(size / 2) / 2) ** 2


def _per_robot(module: nn.Module, x: torch.Tensor) -> torch.Tensor:
    """Apply a module over (..., C, H, W) maps with any leading dims (worlds, time, robots)."""
    return module(x.reshape(-1, *x.shape[-3:])).reshape(*x.shape[:-3], -1)


def _shapes(cfg: EnvConfig, pool: int = 0) -> dict[str, int]:
    """The sizes the networks are built from: classes C, local side L, actions A, and the map side S
    (only without ``pool``: a pooled network plays any map size)."""
    shapes = {"classes": cfg.num_classes, "local": cfg.local_size, "actions": cfg.window**2}
    return shapes | ({"pool": pool} if pool else {"size": cfg.map_size})


class PolicyNet(nn.Module):
    """Per-robot action logits (..., A) from the robot's float global map (..., 5 + C, S, S), local map
    (..., 4 + C, L, L) and class one-hot (..., C)."""

    def __init__(
        self,
        classes: int,
        local: int,
        actions: int,
        size: int | None = None,
        pool: int = 0,
        hidden: int = 128,
    ) -> None:
        super().__init__()
        self.global_trunk, features = conv_trunk(5 + classes, size, pool)
        inputs = features + (4 + classes) * local * local + classes
        self.head = nn.Sequential(
            nn.Linear(inputs, hidden),
            nn.ReLU(),
            nn.Linear(hidden, hidden),
            nn.ReLU(),
            nn.Linear(hidden, actions),
        )

    def forward(self, global_map: torch.Tensor, local_map: torch.Tensor, agent_class: torch.Tensor):
        x = torch.cat([_per_robot(self.global_trunk, global_map), local_map.flatten(-3), agent_class], -1)
        return self.head(x)


class Critic(nn.Module):
    """Per-robot value (..., 1). ``centralised`` (MAPPO): from the ground-truth ``state`` (..., 4 + C, S, S)
    stacked on the robot's own global map; otherwise (IPPO) from the robot's own global and local maps."""

    def __init__(
        self,
        classes: int,
        local: int,
        centralised: bool,
        size: int | None = None,
        pool: int = 0,
        hidden: int = 128,
    ) -> None:
        super().__init__()
        self.centralised = centralised
        channels = (5 + classes) + ((4 + classes) if centralised else 0)
        self.trunk, features = conv_trunk(channels, size, pool)
        extra = 0 if centralised else (4 + classes) * local * local
        self.head = nn.Sequential(
            nn.Linear(features + extra + classes, hidden), nn.ReLU(), nn.Linear(hidden, 1)
        )

    def forward(self, state, global_map, local_map, agent_class):
        maps = torch.cat([state, global_map], -3) if self.centralised else global_map
        parts = [_per_robot(self.trunk, maps), agent_class]
        if not self.centralised:
            parts.insert(1, local_map.flatten(-3))
        return self.head(torch.cat(parts, -1))


def make_actor(cfg: EnvConfig, hidden: int = 128, pool: int = 0) -> ProbabilisticActor:
    """The shared policy as a TorchRL actor over ``CatmipEnv``'s float maps (``float_observation_transform``):
    writes ``("robots", "action")`` and its log-prob. ``pool``: the global map pooled to ``pool x pool``
    (any map size), or 0 (flattened: the task's map size only)."""
    net = PolicyNet(**_shapes(cfg, pool), hidden=hidden)
    return ProbabilisticActor(
        TensorDictModule(net, in_keys=list(K.OBS_KEYS), out_keys=[LOGITS]),
        in_keys={"logits": LOGITS, "mask": K.ACTION_MASK},
        out_keys=[K.ACTION],
        distribution_class=MaskedCategorical,
        return_log_prob=True,  # written to K.LOG_PROB = ("robots", "action_log_prob")
    )


def make_critic(cfg: EnvConfig, algo: str, hidden: int = 128, pool: int = 0) -> TensorDictModule:
    """The critic over flat per-robot samples (:func:`decision_samples`), writing the values."""
    if algo not in ALGOS:
        raise ValueError(f"unknown algorithm {algo!r}; choose one of {list(ALGOS)}")
    s = _shapes(cfg, pool)
    net = Critic(s["classes"], s["local"], algo == "mappo", s.get("size"), pool, hidden=hidden)
    return TensorDictModule(
        net, in_keys=[(K.ROBOTS, "state"), *K.OBS_KEYS[:2], K.AGENT_CLASS], out_keys=[K.VALUE]
    )


# -- the asynchronous advantage ---------------------------------------------------------------------------
def _sequences(active, reward, ticks, done, terminated, gamma: float):
    """Each robot's trainable decisions of a (B, T) batch, in order: per (b, n), a list of
    (t, reward R_k, ticks dt_k, next decision row or -1, terminated) -- see the module docstring."""
    b_max, t_max, n_max = active.shape
    out = {}
    for b in range(b_max):
        for n in range(n_max):
            rows = np.flatnonzero(active[b, :, n])
            seq = []
            for k, t in enumerate(rows):
                nxt = rows[k + 1] if k + 1 < len(rows) else t_max
                ends = np.flatnonzero(done[b, t:nxt])
                end = t + ends[0] if len(ends) else nxt - 1  # last row of this macro-action
                if not len(ends) and nxt == t_max:
                    break  # the batch ended first: unfinished
                if len(ends) and not terminated[b, end]:
                    continue  # cut by the horizon: unfinished
                elapsed = np.concatenate([[0], np.cumsum(ticks[b, t:end])])  # ticks since the decision
                ret = float(np.sum(reward[b, t : end + 1, n] * gamma**elapsed))
                dt = int(ticks[b, t : end + 1].sum())
                seq.append((t, ret, dt, -1 if len(ends) else nxt, bool(len(ends))))
            out[(b, n)] = seq
    return out


def decision_samples(data: TensorDict, critic: TensorDictModule, gamma: float, lmbda: float) -> TensorDict:
    """Flat per-robot samples ``(M,)`` of the trainable decisions in a collector batch ``(B, T)`` of
    ``CatmipEnv`` with float maps, with ``("robots", "advantage" | "value_target" | "state_value")`` from
    TorchRL's GAE along each robot's own decisions (discount ``gamma`` per tick)."""
    robots = data.get(K.ROBOTS)
    active = robots.get("active").cpu().numpy()  # (B, T, N)
    reward = data.get(("next", *K.REWARD)).squeeze(-1).cpu().numpy().astype(np.float64)
    ticks = data.get(("next", K.EVENT_TICKS)).squeeze(-1).cpu().numpy()
    done = data.get(("next", "done")).squeeze(-1).cpu().numpy()
    terminated = data.get(("next", "terminated")).squeeze(-1).cpu().numpy()
    seqs = _sequences(active, reward, ticks, done, terminated, gamma)
    # every row where a robot decides and that a trainable decision needs: its own, or the next one's
    needed = {(b, t, n) for (b, n), seq in seqs.items() for t, *_ in seq}
    needed |= {(b, nxt, n) for (b, n), seq in seqs.items() for _, _, _, nxt, _ in seq if nxt >= 0}
    if not needed:
        return TensorDict({}, batch_size=[0])
    rows = sorted(needed)
    where = {r: i for i, r in enumerate(rows)}
    bi, ti, ni = (torch.tensor(x) for x in zip(*rows))
    keys = [k[1] for k in K.OBS_KEYS] + ["action_mask", "action", "action_log_prob"]
    samples = robots[bi, ti, ni].select(*keys)
    samples.set("state", data.get(K.STATE)[bi, ti])  # (R, 4 + C, S, S) the world's ground truth
    flat = TensorDict({K.ROBOTS: samples}, batch_size=[len(rows)])
    with torch.no_grad():
        values = critic(flat.clone(False)).get(K.VALUE).squeeze(-1)  # (R,)
    # TorchRL's GAE over one padded time axis per robot: (robots of all worlds, decisions, 1)
    shape = (len(seqs), max(len(seq) for seq in seqs.values()), 1)
    val, next_val, rew, disc = (torch.zeros(shape) for _ in range(4))
    done_, term_ = torch.ones(shape, dtype=torch.bool), torch.ones(shape, dtype=torch.bool)
    pick = []  # (sequence, position, row) of every trainable decision
    for s, ((b, n), seq) in enumerate(seqs.items()):
        for k, (t, ret, dt, nxt, ended) in enumerate(seq):
            val[s, k, 0] = values[where[(b, t, n)]]
            rew[s, k, 0] = ret
            disc[s, k, 0] = gamma**dt
            if nxt >= 0:
                next_val[s, k, 0] = values[where[(b, nxt, n)]]
            # the lambda-recursion goes on only into the robot's next decision when that one is trainable
            done_[s, k, 0] = not (nxt >= 0 and k + 1 < len(seq) and seq[k + 1][0] == nxt)
            term_[s, k, 0] = ended  # a rescue: no bootstrap
            pick.append((s, k, where[(b, t, n)]))
    adv, target = vec_generalized_advantage_estimate(
        disc, lmbda, val, next_val, rew, done_, term_, time_dim=-2
    )
    s_idx, k_idx, r_idx = (torch.tensor(x) for x in zip(*pick))
    out = flat[r_idx]
    out.set(ADVANTAGE, adv[s_idx, k_idx])
    out.set(VALUE_TARGET, target[s_idx, k_idx])
    out.set(K.VALUE, val[s_idx, k_idx])
    return out


# -- files ------------------------------------------------------------------------------------------------
POLICY_PY = '''"""The policy trained in this folder, as a ``catmip eval`` factory:

    catmip eval --task TASK --method NAME=py:{folder}/policy.py:make_policy --out OUT
"""

from pathlib import Path

from catmip_rl.adapters.torchrl_marl import load_policy


def make_policy(env_config, seed):
    return load_policy(Path(__file__).with_name("policy.pt"), env_config)
'''


def save_policy(
    actor: ProbabilisticActor, cfg: EnvConfig, folder: str | Path, info: dict, pool: int = 0
) -> Path:
    """``policy.pt`` (the actor's weights only), ``policy.json`` (the shapes and ``info``) and
    ``policy.py`` (a ``catmip eval`` factory) in ``folder``, each written atomically."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    with atomic_path(folder / "policy.pt") as tmp:
        torch.save(actor.module[0].module.state_dict(), tmp)
    meta = {"format": FORMAT, "shapes": _shapes(cfg, pool), **info}
    atomic_write_text(folder / "policy.json", json.dumps(meta, indent=2))
    atomic_write_text(folder / "policy.py", POLICY_PY.replace("{folder}", str(folder)))
    return folder / "policy.pt"


def load_policy(path: str | Path, env_config: EnvConfig, deterministic: bool = True) -> TorchRLPolicy:
    """The saved actor as an engine-level policy for ``env_config`` (argmax by default); a ValueError
    naming the file when it is unreadable, :class:`~catmip_env.play.WorldNotSupported` (a ValueError)
    when it was trained for other shapes (another map size or team)."""
    path = Path(path)
    try:
        meta = json.loads(path.with_suffix(".json").read_text())
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # a missing, truncated or foreign file: whatever torch.load raises
        raise ValueError(f"{path} is not a readable saved policy ({type(err).__name__}: {err})") from None
    if meta.get("format") != FORMAT:
        raise ValueError(f"{path.with_suffix('.json')} is not a {FORMAT} policy file")
    pool = int(meta["shapes"].get("pool", 0))  # pooled: any map size; else the one it was trained on
    want = _shapes(env_config, pool)
    if meta["shapes"] != want:
        raise WorldNotSupported(
            f"{path} was trained for {meta['shapes']}, this setting needs {want}: train on its task"
        )
    actor = make_actor(env_config, hidden=meta.get("hidden", 128), pool=pool)
    actor.module[0].module.load_state_dict(state)
    return TorchRLPolicy(
        actor, float_maps=True, deterministic=deterministic, per_robot=True, files=(str(path),)
    )
