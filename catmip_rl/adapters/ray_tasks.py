"""Ray tasks for the benchmark's job runner (``--backend ray``, :mod:`catmip_rl.benchmark.runner`): join
or start a cluster, and map a function over items as Ray tasks (the stable task API of Ray >= 2.40:
``ray.remote``, ``ray.wait``, ``ray.get``, ``ray.cancel``), at most ``workers`` in flight. No torch here:
a planner's chunks play on workers without it."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import Any

__all__ = ["ray_map", "ray_init_config", "import_ray", "RAY_RETRIES"]

RAY_RETRIES = 3
"""How many times Ray plays a task again whose worker died (a lost node, a killed process)."""


def import_ray(what: str = "--backend ray") -> Any:
    """The ``ray`` module, or an ImportError naming the extra that ``what`` (a flag) needs."""
    try:
        import ray
    except ImportError:
        raise ImportError(f"{what} needs the distributed extra: pip install 'catmip[distributed]'") from None
    return ray


def ray_init_config(address: str | None, workers: int) -> dict[str, Any]:
    """``ray.init`` arguments: join ``address``, or start a private cluster on loopback."""
    if address is None:
        return {
            "address": "local",
            "num_cpus": max(workers, os.cpu_count() or 1),
            "include_dashboard": False,
            "_node_ip_address": "127.0.0.1",
            "log_to_driver": True,
        }
    return {"address": address, "log_to_driver": True}


def ray_map(
    fn: Callable[[Any], Any],
    items: Sequence[Any],
    done: Callable[[int, Any], None],
    workers: int,
    address: str | None,
    on_error: Callable[[int, BaseException], Any] | None = None,
    shared: tuple[Callable[[Any], tuple[Any, Any]], Callable[[Any, Any], Any]] | None = None,
) -> None:
    """``done(k, fn(items[k]))`` for every item as its Ray task ends (one CPU each, at most ``workers`` in
    flight, retried :data:`RAY_RETRIES` times if its worker dies). An error ``fn`` raised is raised here
    as it was raised there; a task whose worker was lost past the retries gives ``on_error(k, err)`` where
    given, else a one-line ChildProcessError. On the way out every task left is cancelled; a cluster
    started here is shut down.

    ``shared = (split, join)``: ``split(item)`` gives (the item without its payload, the payload), and
    each distinct payload (the same object; None is none) goes to Ray's object store once, however many
    items carry it; the task plays ``fn(join(light, payload))``. Both module-level functions."""
    ray = import_ray()
    started = not ray.is_initialized()
    if started:
        try:
            ray.init(**ray_init_config(address, workers), logging_level="ERROR")
        except ConnectionError as err:
            raise ConnectionError(f"--backend ray: cannot join the Ray cluster at {address}: {err}") from None
    submit = _submitter(ray, fn, items, shared)
    flying: dict[Any, int] = {}
    queue = list(range(len(items)))
    try:
        while queue or flying:
            while queue and len(flying) < workers:
                k = queue.pop(0)
                flying[submit(k)] = k
            finished, _ = ray.wait(list(flying), num_returns=1)
            for ref in finished:
                k = flying.pop(ref)
                try:
                    result = ray.get(ref)
                except ray.exceptions.RayTaskError as err:  # the function raised: its own error, as here
                    cause = getattr(err, "cause", None)
                    raise (cause if isinstance(cause, Exception) else err) from None
                except ray.exceptions.RayError as err:  # its worker or node was lost past the retries
                    if on_error is None:
                        why = " ".join(str(err).split())[:200]
                        raise ChildProcessError(
                            f"item {k}: the Ray worker playing it was lost {RAY_RETRIES + 1} times ({why})"
                        ) from None
                    result = on_error(k, err)
                done(k, result)
    except BaseException:
        for ref in flying:
            ray.cancel(ref, force=True)
        raise
    finally:
        if started:
            ray.shutdown()


def _submitter(ray: Any, fn: Callable[[Any], Any], items: Sequence[Any], shared) -> Callable[[int], Any]:
    """``submit(k)``: item k as a Ray task of ``fn`` (its shared payload put in the object store once)."""
    remote = ray.remote(num_cpus=1, max_retries=RAY_RETRIES)(fn if shared is None else _joined)
    if shared is None:
        return lambda k: remote.remote(items[k])
    split, join = shared
    stored: dict[int, Any] = {}  # id(payload) -> its object ref (the items keep the payloads alive)

    def submit(k: int) -> Any:
        light, payload = split(items[k])
        if payload is not None and id(payload) not in stored:
            stored[id(payload)] = ray.put(payload)
        return remote.remote(fn, join, light, None if payload is None else stored[id(payload)])

    return submit


def _joined(fn: Callable[[Any], Any], join: Callable[[Any, Any], Any], light: Any, payload: Any) -> Any:
    """A task of :func:`ray_map` with ``shared``: Ray hands the payload over (its object ref resolved)."""
    return fn(join(light, payload))
