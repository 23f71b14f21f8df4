"""src.train's callbacks besides checkpoints: the progress bar in iterations; a plain progress
line, for where the bar shows nothing for minutes (a file: a cluster job's log), to train.log and
to stdout when that is not a terminal (`OffTerminalOnly`); frame strips in TensorBoard."""

from __future__ import annotations

import contextlib
import importlib.util
import logging
import sys
import time

import lightning as L
from lightning.pytorch.callbacks import Callback, RichProgressBar
from omegaconf import DictConfig

from src.metrics.kinematics import Skeleton
from src.plots import frame_strip, window_rows

log = logging.getLogger(__name__)


def progress_line(iteration: int, total: int, rate: float, losses: dict[str, float]) -> str:
    """`iteration 120/20000 (0.6%) | 0.61 it/s | ETA 9h03m | loss_g 0.0412 ...`"""
    eta = "?"
    if rate > 0:
        minutes, s = divmod(int(round((total - iteration) / rate)), 60)
        h, m = divmod(minutes, 60)
        eta = f"{h}h{m:02d}m" if h else f"{m}m{s:02d}s" if m else f"{s}s"
    parts = [f"iteration {iteration}/{total} ({100 * iteration / max(total, 1):.1f}%)",
             f"{rate:.3g} it/s", f"ETA {eta}"]  # fmt: skip
    if losses:
        parts.append(" ".join(f"{name} {value:.4g}" for name, value in losses.items()))
    return " | ".join(parts)


class ProgressLog(Callback):
    """Logs `progress_line` at most every `every_s` seconds (0: every iteration), on rank 0.
    The rate counts validations too: the ETA is the time the run will really take."""

    def __init__(self, total: int, every_s: float):
        self.total, self.every_s = int(total), float(every_s)
        self._start = self._last = self._first = 0

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._start = self._last = time.monotonic()
        self._first = trainer.global_step

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        now = time.monotonic()
        if now - self._last < self.every_s or not trainer.is_global_zero:
            return
        self._last, iteration = now, trainer.global_step
        rate = (iteration - self._first) / max(now - self._start, 1e-9)
        losses = {
            name.removeprefix("train/"): float(value)
            for name, value in trainer.callback_metrics.items()
            if name.startswith("train/loss") and not name.endswith("_bar")
        }
        log.info("%s", progress_line(iteration, self.total, rate, losses))


class OffTerminalOnly(logging.Filter):
    """For the console handler: progress lines pass only when stdout is not a terminal."""

    def filter(self, record: logging.LogRecord) -> bool:
        with contextlib.suppress(AttributeError, ValueError):  # replaced or closed stdout
            return record.name != __name__ or not sys.stdout.isatty()
        return True


class IterationBar(RichProgressBar):
    """Lightning's Rich bar labelled in iterations: the schedule's one endless epoch would read
    "Epoch 0/-2"."""

    def _get_train_description(self, current_epoch: int) -> str:
        return "iterations"


def iteration_bar() -> list[Callback]:
    """IterationBar where rich is installed (where Lightning would show its Rich bar); else
    Lightning's own bar."""
    return [IterationBar()] if importlib.util.find_spec("rich") else []


class FrameStripLogger(Callback):
    """A frame strip in TensorBoard (`media/...`): prediction, ground truth and zero-velocity of
    the first evaluation window every `every_n_validations` validations, one forward pass, one
    figure. Not in the sanity check, under fast_dev_run, or without a logger that takes figures."""

    def __init__(self, every_n_validations: int = 1):
        if every_n_validations < 1:
            raise ValueError(f"every_n_validations={every_n_validations} must be >= 1")
        self.every_n_validations = every_n_validations
        self._validations = 0

    @classmethod
    def from_config(cls, cfg: DictConfig) -> list[FrameStripLogger]:
        """[logger] for `media_every: n` (n >= 1), [] for 0 or absent."""
        every = int(cfg.get("media_every") or 0)
        return [cls(every_n_validations=every)] if every > 0 else []

    def on_validation_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.sanity_checking or trainer.fast_dev_run or not trainer.is_global_zero:
            return
        self._validations += 1
        if self._validations % self.every_n_validations:
            return
        experiment, dm = getattr(trainer.logger, "experiment", None), trainer.datamodule
        if not hasattr(experiment, "add_figure") or not getattr(dm, "eval_windows", None):
            return
        rows, n_obs, what = window_rows(dm, pl_module, 0, observed_shown=10)
        step = trainer.global_step
        fig = frame_strip(
            rows, Skeleton.load(pl_module.dataset), n_obs, dm.frame_ms, step=4, n_before=2,
            title=f"{what}, iteration {step}",
        )  # fmt: skip
        experiment.add_figure(f"media/{dm.eval_windows[0].action}_window0", fig, global_step=step)
