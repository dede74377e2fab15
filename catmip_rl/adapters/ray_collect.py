"""Collection on Ray workers through TorchRL's :class:`~torchrl.collectors.distributed.RayCollector`.

``--collector ray`` splits the B worlds of an iteration over W remote workers. Worker ``w`` is a Ray
actor running :class:`ShardCollector` (a TorchRL collector class): it owns a
:class:`~catmip_rl.training.collect.Collector` over ``B / W`` worlds of the event engine and, for an iteration
whose first episode is ``E``, collects episodes ``E + w * B/W ... E + (w+1) * B/W - 1``, so that the
workers together collect exactly the episodes of the local collector, in the same order. Actions are
sampled from a generator seeded by (run seed, the worker's first episode): a run is reproducible for
a given worker count.

Each iteration the driver pushes the current weights through RayCollector's weight sync
(:meth:`update_policy_weights_`, a :class:`~torchrl.weight_update.RayWeightSyncScheme`), and
RayCollector's synchronous iterator gathers one TensorDict per worker (batch ``[B/W]``: one row per
world, time padded to ``horizon_ticks + 1`` so that the workers' batches stack) and stacks them;
:class:`RayRolloutCollector` turns the stack back into one :class:`~catmip_rl.training.collect.Rollout`
(worlds in episode order, time trimmed to the longest episode) for ``build_batch`` and PPO.
"""

from __future__ import annotations

import datetime
import functools
from collections import OrderedDict
from collections.abc import Iterator
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict
from torchrl.collectors import BaseCollector

from catmip_env.config import EnvConfig
from catmip_env.engines.episode_stats import EpisodeRecords, training_stats
from catmip_rl.adapters.ray_tasks import import_ray, ray_init_config
from catmip_rl.amat.model import AMAT
from catmip_rl.training.collect import STEP_FIELDS, Collector, Rollout, cpu_mirror
from catmip_rl.training.sections import CollectionSection

__all__ = ["ShardCollector", "RayRolloutCollector"]


def _sampling_seed(seed: int, first_episode: int) -> int:
    """Seed of a worker's sampling generator for the shard starting at ``first_episode``."""
    return int(np.random.SeedSequence([seed, first_episode]).generate_state(1, np.uint64)[0])


class ShardCollector(BaseCollector):
    """TorchRL collector over one Ray worker's share of worlds: one TensorDict per iteration.

    ``create_env_fn`` builds the worker's :class:`Collector`; ``policy`` is the AMAT whose weights
    RayCollector's weight sync overwrites. The other TorchRL collector arguments RayCollector passes
    (frames, devices, exploration, ...) do not apply and are ignored.
    """

    def __init__(
        self,
        create_env_fn: Any,
        policy: AMAT | None = None,
        *,
        policy_factory: Any = None,
        worker_idx: int = 0,
        seed: int = 0,
        pad_steps: int = 1,
        threads: int = 1,
        **_torchrl_kwargs: Any,
    ) -> None:
        super().__init__()
        torch.set_num_threads(threads)
        make = create_env_fn[0] if isinstance(create_env_fn, (list, tuple)) else create_env_fn
        self.collector: Collector = make()
        self.policy = (policy if policy is not None else policy_factory()).cpu()
        self.worker_idx = worker_idx
        self.seed = seed
        self.pad_steps = pad_steps
        self.share = self.collector.engine.num_worlds
        self.first_episode = 0
        self.deterministic = False
        self.total_frames = -1
        self.requested_frames_per_batch = self.frames_per_batch = self.share

    def plan(self, first_episode: int, deterministic: bool = False) -> None:
        """Set the first episode of the iteration (over all workers) that the next batch is part of."""
        self.first_episode = first_episode
        self.deterministic = deterministic

    def _batch(self) -> TensorDict:
        first = self.first_episode + self.worker_idx * self.share
        gen = torch.Generator().manual_seed(_sampling_seed(self.seed, first))
        r = self.collector.collect(self.policy, first, generator=gen, deterministic=self.deterministic)
        b, t = self.share, r.steps
        data = {}
        for key in STEP_FIELDS:
            arr = getattr(r, key)
            padded = np.zeros((b, self.pad_steps) + arr.shape[2:], arr.dtype)
            padded[:, :t] = arr.swapaxes(0, 1)
            data[key] = torch.from_numpy(padded)
        data["final_return"] = torch.from_numpy(r.final_return)
        data["terminated"] = torch.from_numpy(r.terminated)
        data["steps"] = torch.full((b,), t, dtype=torch.int64)
        data["episode"] = torch.arange(first, first + b)
        # the episodes' records, one row per world: the driver concatenates them and computes the
        # statistics once, as the local collector does
        data["records"] = {k: torch.from_numpy(v) for k, v in vars(r.records).items()}
        data["returns"] = torch.from_numpy(r.returns)
        return TensorDict(data, batch_size=[b], device="cpu")

    def iterator(self) -> Iterator[TensorDict]:
        while True:
            yield self._batch()

    def _maybe_fallback_update(self, policy_or_weights: Any = None, *, model_id: str | None = None) -> None:
        """Weights handed to this collector go into its policy (received ones are in place already)."""
        if policy_or_weights is None:
            return
        weights = policy_or_weights
        if isinstance(weights, torch.nn.Module):
            weights = TensorDict.from_module(weights)
        TensorDict.from_module(self.policy).data.update_(weights)

    def set_seed(self, seed: int, static_seed: bool = False) -> int:
        self.seed = seed
        return seed

    def state_dict(self) -> OrderedDict:
        return OrderedDict(first_episode=self.first_episode, seed=self.seed)

    def load_state_dict(self, state_dict: OrderedDict, strict: bool = True) -> None:
        self.first_episode = state_dict["first_episode"]
        self.seed = state_dict["seed"]

    def shutdown(
        self, timeout: float | None = None, close_env: bool = True, raise_on_error: bool = True
    ) -> None:
        """Nothing to release: the worker's engine is plain memory."""

    @classmethod
    def as_remote(cls, remote_config: dict[str, Any] | None = None):
        """The Ray actor class RayCollector instantiates on the workers."""
        ray = import_ray("--collector ray")
        return ray.remote(**(remote_config or {}))(cls)


class RayRolloutCollector:
    """Driver side of ``--collector ray``: ``collect`` returns the same :class:`Rollout` as
    :meth:`Collector.collect` would (``Collector(env, collection.num_worlds, seed, gamma)``), gathered
    from ``collection.ray_workers`` Ray workers (``collection``: a TrainConfig's section).

    Joins the cluster at ``collection.ray_address`` or, when it is None and Ray is not initialised yet,
    starts a local one (shut down again by :meth:`close`).
    """

    def __init__(
        self, env: EnvConfig, collection: CollectionSection, seed: int, gamma: float, model: AMAT
    ) -> None:
        from torchrl.collectors.distributed import RayCollector
        from torchrl.weight_update import _ray as weight_sync

        # TorchRL's weight-sync rendezvous waits 60 s for a fresh Ray worker that imports torch and
        # torchrl; on a busy small machine that import alone can take longer, so allow more time
        if getattr(weight_sync, "_DIST_TIMEOUT", None) is not None:
            weight_sync._DIST_TIMEOUT = max(weight_sync._DIST_TIMEOUT, datetime.timedelta(minutes=10))

        self.env = env
        self.workers = collection.ray_workers
        self.num_worlds = collection.num_worlds  # episodes a collect() call plays, as Collector.num_worlds
        self.model = model
        ray_init = ray_init_config(collection.ray_address, self.workers)
        self._mirror = cpu_mirror(model)
        share = self.num_worlds // self.workers
        goals = model.config.goals  # a cell-goal model plays an engine in cell goal mode
        make = functools.partial(Collector, env, share, seed, gamma, goal_mode=goals)
        try:
            self._rc = RayCollector(
                make,
                policy=self._mirror,
                collector_class=ShardCollector,
                collector_kwargs={"seed": seed, "pad_steps": env.horizon_ticks + 1},
                num_collectors=self.workers,
                remote_configs={"num_cpus": 1},
                ray_init_config=ray_init,
                frames_per_batch=self.num_worlds,  # a frame is a world's episode here
                total_frames=2**62,  # endless: the training loop decides when to stop (-1 ends at once)
                sync=True,
            )
        except ConnectionError as err:  # nothing at that address, a missing auth token, ...
            raise RuntimeError(
                f"--collector ray: cannot join the Ray cluster at {collection.ray_address}: {err}"
            ) from err
        # wait until every worker is built (imports, numba, engine): the weight sync's rendezvous
        # at the first update then only waits for the connection (TorchRL gives it 60 s)
        self._rc.map_fn("plan", [(0, False)] * self.workers)
        self._iter = iter(self._rc)

    def collect(
        self,
        model: AMAT,
        first_episode: int,
        generator: torch.Generator | None = None,
        deterministic: bool = False,
        labeler: None = None,
    ) -> Rollout:
        """One episode per world (indices ``first_episode + b``) with ``model``'s current weights
        (``generator`` is unused: each worker seeds its own; no ``labeler``: TrainConfig refuses labels
        with Ray, the workers would need the planner)."""
        if model is not self.model:
            raise ValueError("RayRolloutCollector.collect: pass the model it was built with")
        cpu_mirror(model, self._mirror)  # the weights the workers fetch
        self._rc.update_policy_weights_()
        self._rc.map_fn("plan", [(first_episode, deterministic)] * self.workers)
        td = next(self._iter).reshape(-1)  # (W, B/W) -> (B,) worlds in episode order
        episodes = td["episode"].numpy()
        if not np.array_equal(episodes, np.arange(first_episode, first_episode + len(episodes))):
            raise RuntimeError(f"ray workers returned episodes {episodes.tolist()} out of order")
        t = int(td["steps"].max())
        arrays = {k: np.ascontiguousarray(td[k][:, :t].numpy().swapaxes(0, 1)) for k in STEP_FIELDS}
        records = EpisodeRecords(**{k: v.numpy().copy() for k, v in td["records"].items()})
        returns = td["returns"].numpy().copy()
        return Rollout(
            **arrays,
            label=None,
            label_relay=None,
            state=None,  # a state critic collects locally (TrainConfig refuses it with Ray)
            final_return=td["final_return"].numpy().copy(),
            terminated=td["terminated"].numpy().copy(),
            records=records,
            returns=returns,
            stats=training_stats(records, returns, self.env),
        )

    def close(self) -> None:
        """Stop the workers (and the local Ray cluster if this collector started it)."""
        self._rc.shutdown()
