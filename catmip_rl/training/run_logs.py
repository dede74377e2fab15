"""What a training run writes and shows: the columns of its logs, the logs themselves (CSV and
TensorBoard) and its progress bar."""

from __future__ import annotations

import math
from pathlib import Path

from catmip_rl.store.files import open_csv_log, write_csv_row
from catmip_rl.training.run_dir import tensorboard_writer

__all__ = ["METRICS", "EPOCH_METRICS", "RunLogs", "progress_bar", "show_progress"]

METRICS = [
    "iteration",
    "episodes",
    "samples",
    "rollout/success_rate",
    "rollout/success_by_100",
    "rollout/mean_rescue_tick",
    "rollout/target_found_rate",
    "rollout/mean_target_found_tick",
    "rollout/mean_explored_fraction",
    "rollout/mean_episode_ticks",
    "rollout/return_rescuer",
    "rollout/return_explorer",
    "rollout/decisions_per_episode",
    "rollout/stalls_per_episode",
    "rollout/stall_fraction_rescuer",
    "rollout/stall_fraction_explorer",
    "rollout/world",
    "loss/policy",
    "loss/value",
    "loss/entropy",
    "loss/rescue",
    "ppo/approx_kl",
    "ppo/clip_fraction",
    "ppo/grad_norm",
    "ppo/lr",
    "ppo/epochs",
    "ppo/early_stop",
    "ppo/bf16",
    "ppo/explained_variance",
    "eval/success_rate",
    "eval/success_by_100",
    "eval/mean_rescue_tick",
    "eval/mean_target_found_tick",
    "eval/mean_explored_fraction",
    "eval/decisions_per_episode",
    "eval/stalls_per_episode",
    "eval/stall_fraction_rescuer",
    "eval/stall_fraction_explorer",
    "eval/sampled_success_rate",
    "eval/sampled_success_by_100",
    "time/collect_s",
    "time/advantage_s",
    "time/update_s",
    "time/iteration_s",
    "time/elapsed_min",
]
EPOCH_METRICS = [
    "iteration",
    "epoch",
    "loss/policy",
    "loss/value",
    "loss/entropy",
    "ppo/approx_kl",
    "ppo/clip_fraction",
]


class RunLogs:
    """A run's logs: metrics.csv and ppo_epochs.csv (continued from the checkpoint on resume) and
    TensorBoard (None without it), each opened by :meth:`open` in turn; :meth:`close` closes those open."""

    def __init__(self) -> None:
        self.csv_file = self.epoch_file = self.tb = None
        self.csv_writer = self.epoch_writer = None

    def open(self, run_dir: Path, start: int | None) -> None:
        self.csv_file, self.csv_writer = open_csv_log(run_dir / "metrics.csv", METRICS, start)
        self.epoch_file, self.epoch_writer = open_csv_log(run_dir / "ppo_epochs.csv", EPOCH_METRICS, start)
        self.tb = tensorboard_writer(run_dir)

    def scalars(self, row: dict, step: int, skip: str) -> None:
        """The numbers of ``row`` (not NaN, not the column ``skip``) to TensorBoard at ``step``."""
        if self.tb is not None:
            for k, v in row.items():
                if k != skip and isinstance(v, (int, float)) and not math.isnan(v):
                    self.tb.add_scalar(k, v, step)

    def write(self, it: int, row: dict, epochs: list[dict[str, float]]) -> None:
        """PPO iteration ``it``'s metrics row and its epochs' statistics, to TensorBoard and the CSVs."""
        self.scalars(row, it, "iteration")
        write_csv_row(self.csv_writer, self.csv_file, row)
        for e in epochs:
            write_csv_row(self.epoch_writer, self.epoch_file, {"iteration": it} | e)

    def close(self) -> None:
        for log in (self.csv_file, self.epoch_file, self.tb):
            if log is not None:
                log.close()


def progress_bar(iterations: int, done: int, progress: bool):
    """A tqdm bar over a run's ``iterations`` PPO iterations, ``done`` of them behind it (None without
    ``progress``)."""
    if not progress:
        return None
    from tqdm import tqdm

    return tqdm(total=iterations, initial=done, desc="train", unit="it")


def show_progress(bar, row: dict) -> None:
    """One more iteration on ``bar``, with its success rate, KL and time."""
    bar.update(1)
    bar.set_postfix(
        success=f"{row.get('rollout/success_rate', 0):.2f}",
        kl=f"{row['ppo/approx_kl']:.4f}",
        t=f"{row['time/iteration_s']:.1f}s",
    )
