"""The benchmark suite ``run_all.py`` runs: each script, its ``--quick`` arguments, what happened to it."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Bench", "BENCHES", "NAMES", "RunStatus"]


@dataclass(frozen=True)
class Bench:
    """One benchmark script and the arguments ``--quick`` gives it."""

    name: str
    script: str
    quick: tuple[str, ...]
    takes_seconds: bool  # accepts --seconds (overridden by run_all's --seconds)


BENCHES = (
    Bench("engine", "bench_engine.py", ("--seconds", "1", "--batches", "1", "64"), True),
    Bench("events", "bench_events.py", ("--seconds", "1", "--decisions", "100"), True),
    Bench("amat", "bench_amat.py", ("--repeats", "30", "--train-steps", "3", "--bf16-steps", "1"), False),
    Bench("train", "bench_train.py", ("--iterations", "2", "--epochs", "2"), False),
    Bench("scaling", "bench_scaling.py", ("--seconds", "0.5"), True),
    Bench("executor", "bench_executor.py", ("--events", "6"), False),
    Bench("threads", "bench_threads.py", ("--events", "40", "--repeats", "1"), False),
    Bench("peer", "bench_peer.py", ("--steps", "3000", "--rounds", "1"), False),
)
NAMES = tuple(b.name for b in BENCHES)


@dataclass
class RunStatus:
    """What happened to one benchmark in this invocation."""

    name: str
    ran: bool = False
    ok: bool = False
    returncode: int | None = None
    seconds: float = 0.0
    command: str = ""
    error: str = ""  # last lines of output when it failed
