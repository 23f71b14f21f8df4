"""Train a motion predictor.

    python -m src.train model=conv_s2s data=cmu
    python -m src.train experiment=li2018_h36m
    python -m src.train -m model=conv_s2s,gru_s2s data=cmu      (a sweep)
    python -m src.train ckpt_path=outputs/train/runs/.../checkpoints/last.ckpt   (resume)

Returns the best average validation error (Euler, radians), which Hydra's sweepers minimise.
"""

from __future__ import annotations

import logging
import math
import os
import time
from pathlib import Path

import hydra
import lightning as L
import torch
from lightning.pytorch.callbacks import LearningRateMonitor, ModelCheckpoint
from lightning.pytorch.loggers import TensorBoardLogger
from omegaconf import DictConfig, OmegaConf

from src.lit.factory import (
    ConfigError,
    build_datamodule,
    build_module,
    check_compatible,
    check_normalizer,
    git_commit,
    read_checkpoint,
    register_resolvers,
)
from src.lit.validation import friendly_errors, validate_train_config
from src.reporting.tensorboard import add_error_curve_layout

log = logging.getLogger(__name__)
register_resolvers()


def _check_writable(folder: Path) -> None:
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / ".write_test"
        probe.write_text("ok")
        probe.unlink()
    except OSError as err:
        raise ConfigError(
            f"cannot write the run folder {folder}: {err}. Set hydra.run.dir (or "
            "paths.log_dir) to a writable place."
        ) from err


def train(cfg: DictConfig) -> float:
    validate_train_config(cfg)
    out_dir = Path(cfg.paths.output_dir)
    _check_writable(out_dir)
    L.seed_everything(cfg.seed, workers=True)
    torch.use_deterministic_algorithms(True, warn_only=True)

    dm = build_datamodule(cfg.data)
    dm.prepare_data()
    dm.setup("fit")

    ckpt = None
    if cfg.ckpt_path:
        ckpt = read_checkpoint(cfg.ckpt_path)
        check_compatible(ckpt, cfg, cfg.ckpt_path)
        check_normalizer(ckpt, dm.normalizer, cfg.ckpt_path)

    run_info = {
        "config": {
            key: OmegaConf.to_container(cfg[key], resolve=True)
            for key in ("model", "data", "sampling", "adversarial", "metrics")
        },
        "commit": git_commit(),
        "missing_files": list(dm.missing_files),
    }
    module = build_module(cfg, dm, run_info=run_info)
    dm.draws_per_step = 2 if module.adversarial else 1

    logger = TensorBoardLogger(
        save_dir=str(out_dir), name="tensorboard", version="", default_hp_metric=False
    )
    checkpoints = ModelCheckpoint(
        dirpath=out_dir / "checkpoints",
        # No "=" in file names: Hydra's override parser would choke on ckpt_path=...
        filename="best-epoch{epoch:03d}",
        auto_insert_metric_name=False,
        monitor="val/euler_avg",
        mode="min",
        save_last=True,
        save_top_k=1,
    )
    trainer: L.Trainer = hydra.utils.instantiate(
        cfg.trainer,
        max_epochs=math.ceil(cfg.iterations / cfg.val_every),
        logger=logger,
        callbacks=[checkpoints, LearningRateMonitor(logging_interval="step")],
    )
    if trainer.logger is not None and trainer.is_global_zero:
        add_error_curve_layout(logger.experiment, dm.actions, module.horizons)
        OmegaConf.save(cfg, out_dir / "config.yaml", resolve=True)

    start = time.perf_counter()
    trainer.fit(module, datamodule=dm, ckpt_path=cfg.ckpt_path)
    wall = time.perf_counter() - start

    best = checkpoints.best_model_score
    score = (
        float(best)
        if best is not None
        else float(trainer.callback_metrics.get("val/euler_avg", torch.tensor(float("nan"))))
    )
    if trainer.is_global_zero and not cfg.trainer.get("fast_dev_run"):
        summary = {
            "best_val_euler_avg": score,
            "best_checkpoint": checkpoints.best_model_path,
            "last_checkpoint": checkpoints.last_model_path,
            "iterations": int(module.iteration),
            "wall_time_s": round(wall, 1),
            "commit": run_info["commit"],
            "device": _device_name(trainer),
        }
        OmegaConf.save(OmegaConf.create(summary), out_dir / "summary.yaml")
        log.info("run folder: %s", out_dir)
        log.info("best average validation Euler error: %.4f", score)
    return score


def _device_name(trainer: L.Trainer) -> str:
    if trainer.accelerator.__class__.__name__.startswith("CUDA") and torch.cuda.is_available():
        return torch.cuda.get_device_name(0)
    return f"cpu ({os.cpu_count()} cores, {torch.get_num_threads()} threads)"


@hydra.main(version_base="1.3", config_path="../conf", config_name="train")
@friendly_errors
def main(cfg: DictConfig) -> float:
    return train(cfg)


if __name__ == "__main__":
    main()
