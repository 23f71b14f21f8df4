"""A plain progress line where there is no terminal: the progress bar, sent to a file (a
cluster job's log), shows nothing for minutes. It goes to train.log, and to stdout when that is
not a terminal (`OffTerminalOnly`, conf/hydra/default.yaml)."""

from __future__ import annotations

import contextlib
import importlib.util
import logging
import sys
import time

import lightning as L
from lightning.pytorch.callbacks import Callback, RichProgressBar

log = logging.getLogger(__name__)


def progress_line(iteration: int, total: int, rate: float, losses: dict[str, float]) -> str:
    """`iteration 120/20000 (0.6%) | 0.61 it/s | ETA 9h03m | loss_g 0.0412 ...`"""
    eta = "?"
    if rate > 0:
        minutes, s = divmod(int(round((total - iteration) / rate)), 60)
        h, m = divmod(minutes, 60)
        eta = f"{h}h{m:02d}m" if h else f"{m}m{s:02d}s" if m else f"{s}s"
    parts = [
        f"iteration {iteration}/{total} ({100 * iteration / max(total, 1):.1f}%)",
        f"{rate:.3g} it/s",
        f"ETA {eta}",
    ]
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
        self._last = now
        iteration = trainer.global_step
        rate = (iteration - self._first) / max(now - self._start, 1e-9)
        losses = {
            name.removeprefix("train/"): float(value)
            for name, value in trainer.callback_metrics.items()
            if name.startswith("train/loss") and not name.endswith("_bar")
        }
        log.info("%s", progress_line(iteration, self.total, rate, losses))


class IterationBar(RichProgressBar):
    """Lightning's Rich bar labelled in iterations: the schedule's one endless epoch would read
    "Epoch 0/-2"."""

    def _get_train_description(self, current_epoch: int) -> str:
        return "iterations"


def iteration_bar() -> list[Callback]:
    """IterationBar where rich is installed (where Lightning would show its Rich bar); else
    Lightning's own bar."""
    return [IterationBar()] if importlib.util.find_spec("rich") else []


class OffTerminalOnly(logging.Filter):
    """For the console handler: progress lines pass only when stdout is not a terminal."""

    def filter(self, record: logging.LogRecord) -> bool:
        with contextlib.suppress(AttributeError, ValueError):  # replaced or closed stdout
            return record.name != __name__ or not sys.stdout.isatty()
        return True
