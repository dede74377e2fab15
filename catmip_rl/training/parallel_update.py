"""Data-parallel PPO gradients on a multi-core CPU: this process and helper processes, one torch thread
each, every one taking its share of a minibatch's micro-batches.

On CPUs with few cores a training step's small convolutions, matrix products and elementwise ops scale
poorly over threads (two threads run a Task-2 step ~1.5x faster than one), while two single-threaded
processes, each with its own micro-batches, do twice the work of one (~15 % more agent-samples/s than one
process with two threads on the 2-core machine; docs/speed.md). The PPO update is a sum of
micro-batch gradients, so it splits without approximation::

    with ParallelGradients(model, processes=2, **loss_kwargs) as grads:
        grads.set_batch(batch)                      # once per iteration: shared memory, no copies
        stats = grads.backward(model, parts, count)  # per minibatch: .grad of model = the sum
        ...clip, optimiser step on this process only

The helpers hold a copy of the model's parameters only (no optimiser): before each minibatch they load
the current parameters from a shared buffer and return their micro-batches' gradient through another;
this process adds them to its own. Micro-batch ``j`` of a minibatch goes to process ``j % processes``
(this process is 0) and the sum runs in a fixed order, so results do not depend on timing; they equal
the one-process update to float32 rounding (the order of the micro-batch sum differs).
"""

from __future__ import annotations

import dataclasses
import traceback
from typing import Any

import torch
import torch.multiprocessing as mp

from catmip_rl.amat.config import AmatConfig
from catmip_rl.amat.model import AMAT
from catmip_rl.amat.pointer import make_model
from catmip_rl.training.gae import SampleBatch
from catmip_rl.training.ppo import accumulate_gradients

__all__ = ["ParallelGradients"]


def _pack(tensors: list[torch.Tensor], out: torch.Tensor) -> None:
    """out (P,) = the tensors flattened one after another."""
    start = 0
    with torch.no_grad():
        for t in tensors:
            out[start : start + t.numel()].copy_(t.reshape(-1))
            start += t.numel()


def _unpack(flat: torch.Tensor, params: list[torch.Tensor]) -> list[torch.Tensor]:
    """Views of flat (P,) shaped like the parameters, in order."""
    views, start = [], 0
    for p in params:
        views.append(flat[start : start + p.numel()].view_as(p))
        start += p.numel()
    return views


def _helper(conn, config: dict[str, Any], params: torch.Tensor, grads: torch.Tensor, loss_kwargs) -> None:
    """A helper process: one torch thread, a copy of the model, commands from ``conn``."""
    from catmip_rl.training.allocator import keep_freed_memory

    torch.set_num_threads(1)
    keep_freed_memory()
    model = make_model(AmatConfig(**config)).train()
    batch = None
    while True:
        try:
            msg = conn.recv()
        except EOFError:  # the training process is gone
            return
        try:
            if msg[0] == "stop":
                return
            if msg[0] == "batch":
                batch = msg[1]
                conn.send(("ok", None))
            elif msg[0] == "backward":
                _, parts, count = msg
                own = list(model.parameters())
                with torch.no_grad():
                    for p, value in zip(own, _unpack(params, own)):
                        p.copy_(value)
                model.zero_grad(set_to_none=True)
                sums = accumulate_gradients(model, batch, parts, count, **loss_kwargs)
                _pack([torch.zeros_like(p) if p.grad is None else p.grad for p in own], grads)
                conn.send(("ok", sums))
        except Exception:  # reported to the training process, which raises it
            conn.send(("error", traceback.format_exc()))


class ParallelGradients:
    """``processes - 1`` helper processes computing PPO gradients with this one (see the module).

    Parameters
    ----------
    model : AMAT
        The model being trained (CPU); helpers build a copy of its architecture.
    processes : int
        Processes computing gradients, this one included (>= 2).
    **loss_kwargs
        ``accumulate_gradients`` keyword arguments (clip, value_clip, huber_delta, entropy_coef,
        value_coef, bf16).
    """

    def __init__(self, model: AMAT, processes: int, **loss_kwargs: Any) -> None:
        if not isinstance(processes, int) or processes < 2:
            raise ValueError(f"ParallelGradients needs processes >= 2, got {processes!r}")
        if any(p.device.type != "cpu" for p in model.parameters()):
            raise ValueError("ParallelGradients runs on CPU: the model's parameters must be on the CPU")
        self.processes, self.loss_kwargs = processes, dict(loss_kwargs)
        numel = sum(p.numel() for p in model.parameters())
        self._params = torch.zeros(numel).share_memory_()
        self._grads = [torch.zeros(numel).share_memory_() for _ in range(processes - 1)]
        ctx = mp.get_context("spawn")  # not fork: this process runs OpenMP and numba threads
        self._conns, self._procs = [], []
        self._batch: SampleBatch | None = None
        config = dataclasses.asdict(model.config)
        try:
            for grads in self._grads:
                parent, child = ctx.Pipe()
                proc = ctx.Process(
                    target=_helper, args=(child, config, self._params, grads, self.loss_kwargs), daemon=True
                )
                proc.start()
                child.close()
                self._conns.append(parent)
                self._procs.append(proc)
        except BaseException:
            self.close()
            raise

    def _replies(self) -> list[Any]:
        """Every helper's answer to the last command (all of them read, so none is left in a pipe);
        raises the first helper's error."""
        replies, errors = [], []
        for i, conn in enumerate(self._conns):
            try:
                status, value = conn.recv()
            except EOFError:
                status, value = "died", f"exit code {self._procs[i].exitcode}"
            if status != "ok":
                what = "failed" if status == "error" else status
                errors.append(f"gradient helper process {i + 1} {what}:\n{value}")
            replies.append(value)
        if errors:
            raise RuntimeError(errors[0])
        return replies

    def set_batch(self, batch: SampleBatch) -> None:
        """Hand the helpers the iteration's batch: its tensors move to shared memory (no copies later)."""
        self._batch = batch.map(lambda v: v.cpu().share_memory_())
        for conn in self._conns:
            conn.send(("batch", self._batch))
        self._replies()

    def backward(
        self, model: AMAT, parts: list[torch.Tensor], count: torch.Tensor | float
    ) -> dict[str, float]:
        """The summed gradient of ``ppo_loss`` over the micro-batches ``parts`` (index tensors into the
        batch given to ``set_batch``) into ``model``'s .grad, which must start as None or zero; returns
        the loss parts summed over the micro-batches. Runs on one torch thread here."""
        if self._batch is None:
            raise RuntimeError("ParallelGradients.backward before set_batch: the helpers hold no batch")
        batch, count = self._batch, float(count)
        params = list(model.parameters())
        _pack(params, self._params)
        for i, conn in enumerate(self._conns):
            conn.send(("backward", parts[i + 1 :: self.processes], count))
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            sums = accumulate_gradients(model, batch, parts[:: self.processes], count, **self.loss_kwargs)
        except BaseException:
            try:
                self._replies()  # leave no answer in the pipes for the next call
            finally:
                torch.set_num_threads(threads)
            raise
        torch.set_num_threads(threads)
        for reply, grads in zip(self._replies(), self._grads):
            for k, v in reply.items():
                sums[k] = sums.get(k, 0.0) + v
            with torch.no_grad():
                for p, g in zip(params, _unpack(grads, params)):
                    if p.grad is None:
                        p.grad = g.clone()
                    else:
                        p.grad.add_(g)
        return sums

    def close(self) -> None:
        """Stop the helpers (also on garbage collection and at exit: they are daemons)."""
        for conn in self._conns:
            try:
                conn.send(("stop",))
                conn.close()
            except (OSError, BrokenPipeError):
                pass
        for proc in self._procs:
            proc.join(timeout=10)
            if proc.is_alive():
                proc.terminate()
        self._conns, self._procs = [], []

    def __enter__(self) -> ParallelGradients:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
