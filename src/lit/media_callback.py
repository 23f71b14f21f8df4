"""A frame strip of one evaluation window in TensorBoard (`media/...`) after validations."""

from __future__ import annotations

import lightning as L
from lightning.pytorch.callbacks import Callback
from omegaconf import DictConfig

from src.metrics.kinematics import Skeleton
from src.plots import frame_strip, window_rows


class FrameStripLogger(Callback):
    """Prediction, ground truth and zero-velocity of the first evaluation window every
    `every_n_validations` validations: one forward pass, one figure. Not in the sanity check,
    under fast_dev_run, or without a logger that takes figures."""

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
        experiment = getattr(trainer.logger, "experiment", None)
        dm = trainer.datamodule
        if not hasattr(experiment, "add_figure") or not getattr(dm, "eval_windows", None):
            return
        rows, n_obs, what = window_rows(dm, pl_module, 0, observed_shown=10)
        step = trainer.global_step
        fig = frame_strip(
            rows, Skeleton.load(pl_module.dataset), n_obs, dm.frame_ms, step=4, n_before=2,
            title=f"{what}, iteration {step}",
        )  # fmt: skip
        experiment.add_figure(f"media/{dm.eval_windows[0].action}_window0", fig, global_step=step)
