"""Train a motion predictor; return the best average validation error (Euler, radians), which
Hydra's sweepers minimise.

    python -m src.train model=conv_s2s data=cmu
    python -m src.train experiment=li2018_h36m
    python -m src.train -m model=conv_s2s,gru_s2s data=cmu      (a sweep)
    python -m src.train resume=outputs/train/runs/<run>/<time>   (resume in the run's folder)
    python -m src.train ckpt_path=outputs/train/runs/<run>/<time>/checkpoints/last.ckpt
"""

from __future__ import annotations

import logging
import math
import os
import time
from pathlib import Path

import lightning as L
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from lightning.pytorch.callbacks import LearningRateMonitor, Timer
from lightning.pytorch.loggers import TensorBoardLogger
from lightning.pytorch.utilities import rank_zero_only
from omegaconf import DictConfig, OmegaConf

from src.build import build_datamodule, build_module, check_normalizer, require_resumable
from src.cli import git_commit, holds_run, hydra_entry
from src.config import ConfigError, instantiate
from src.lit import checkpoints as ck
from src.lit.callbacks import FrameStripLogger, ProgressLog, iteration_bar
from src.lit.predictor import NonFiniteLossError
from src.metrics.averages import averages
from src.prepare import describe, prepare_training

log = logging.getLogger(__name__)


def add_error_curve_layout(writer, actions: list[str], horizons, averages=None) -> None:
    """Custom scalars: a chart per metric and action (and average), a line per horizon.
    `averages`: src.lit.predictor.averages() of the run; a chart's title names its set where
    there are two (the tag stays `average`: validation_curve reads old runs by it)."""
    titles = {n: f"average ({words})" if words else n for n, (_, words) in (averages or {}).items()}
    charts = {"average": "average"} | titles | {a: a for a in actions}
    layout = {
        f"val {m} error per horizon": {
            title: ["Multiline", [f"val_{m}/{tag}/{ms:04d}ms" for ms in horizons]]
            for tag, title in charts.items()
        }
        for m in ("euler", "mpjpe")
    }
    writer.add_custom_scalars(layout)


def train(cfg: DictConfig) -> float:
    # A resume continues the run's own config (checked on the command line, before the folder).
    hydra_cfg = HydraConfig.get() if HydraConfig.initialized() else None
    overrides = list(hydra_cfg.overrides.task) if hydra_cfg else []
    choices = OmegaConf.to_container(hydra_cfg.runtime.choices) if hydra_cfg else {}
    cfg, resume = prepare_training(cfg, overrides, choices)
    out_dir = Path(cfg.paths.output_dir)
    # A resume from the command line continues in its run's folder (src.prepare.PrepareRun).
    in_place = resume is not None and out_dir.resolve() == resume.run_dir.resolve()
    # E.g. a folder given in-process that holds a run; DDP's other ranks use rank 0's folder.
    if rank_zero_only.rank == 0 and holds_run(out_dir) and not in_place:
        raise ConfigError(
            f"the run folder {out_dir} already holds another run; nothing was overwritten. "
            "Start the run again (it gets a new timestamped folder) or set hydra.run.dir."
        )
    out_dir.mkdir(parents=True, exist_ok=True)  # train(cfg) called from Python: no Hydra claim
    L.seed_everything(cfg.seed, workers=True)

    dm = build_datamodule(cfg.data)
    dm.prepare_data()
    dm.setup("fit")

    ckpt = done = None
    if cfg.ckpt_path:
        ckpt = ck.read_checkpoint(cfg.ckpt_path)
        require_resumable(ckpt, cfg.ckpt_path)
        # Model and data are the run's own (restored above): only the data files may differ.
        check_normalizer(ckpt, dm.normalizer, cfg.ckpt_path)
        done = int(ckpt["global_step"])
        if done >= cfg.iterations:
            raise ConfigError(
                f"{cfg.ckpt_path} is at iteration {done} and the run is {cfg.iterations} "
                "iterations long: nothing to resume. To train it longer, add iterations=N "
                f"(N > {done}, a multiple of val_every={cfg.val_every})."
            )
        if resume is not None:
            log.info("%s", describe(resume, done))

    sections = ("model", "data", "sampling", "adversarial", "metrics")
    run_info = {
        "config": {key: OmegaConf.to_container(cfg[key], resolve=True) for key in sections},
        "commit": git_commit(),
        "missing_files": list(dm.missing_files),
    }
    module = build_module(cfg, dm, run_info=run_info)

    # fast_dev_run swaps the logger for a dummy, but logger.experiment would write events.
    fast_dev_run = bool(cfg.trainer.get("fast_dev_run"))
    logger = TensorBoardLogger(str(out_dir), "tensorboard", version="", default_hp_metric=False)
    every = cfg.progress_every_s
    callbacks = [*FrameStripLogger.from_config(cfg)]
    callbacks += [] if every is None else [ProgressLog(cfg.iterations, every)]
    callbacks += iteration_bar() if cfg.trainer.get("enable_progress_bar", True) else []
    checkpoints = ck.BestCheckpoint(out_dir / "checkpoints")
    last = ck.LastCheckpoint(out_dir / "checkpoints", every=cfg.checkpoint_every)
    module.last_checkpoint = last.path
    # Training time over all of a run's segments: kept in the checkpoint (older ones lack it).
    timer = Timer()
    total_known = ckpt is None or timer.state_key in ckpt.get("callbacks", {})
    trainer: L.Trainer = instantiate(
        cfg.trainer,
        # The schedule: one iteration is one step, the training batches an endless stream.
        max_steps=cfg.iterations,
        val_check_interval=cfg.val_every,
        check_val_every_n_epoch=None,
        logger=logger,
        callbacks=[timer, checkpoints, last, LearningRateMonitor("step"), *callbacks],
    )
    if trainer.is_global_zero:
        if not fast_dev_run:
            evaluated = [a for a in dm.actions if a not in dm.absent_actions]
            sets = averages(evaluated, module.untrained_actions)
            add_error_curve_layout(logger.experiment, dm.actions, module.horizons, sets)
        if in_place:
            keep_earlier(out_dir, done, cfg)
        OmegaConf.save(cfg, out_dir / "config.yaml", resolve=True)

    start = time.perf_counter()
    trainer.fit(module, datamodule=dm, ckpt_path=cfg.ckpt_path)
    wall = time.perf_counter() - start

    metrics = trainer.callback_metrics
    final = {k: float(metrics.get(f"val/{k}", math.nan)) for k in ("euler_avg", "mpjpe_avg")}
    best = checkpoints.best_model_score
    score = float(best) if best is not None else final["euler_avg"]
    best_path = checkpoints.best_model_path  # of the whole run: BestCheckpoint carries it over
    if trainer.is_global_zero and not fast_dev_run:
        summary = {
            "best_val_euler_avg": score,
            "best_checkpoint": best_path,
            "last_checkpoint": str(last.path),
            **{f"final_val_{k}": value for k, value in final.items()},
            "iterations": trainer.global_step,
            "wall_time_s": round(wall, 1),  # this process's
            "train_time_s": round(timer.time_elapsed("train"), 1) if total_known else None,
            "resumed_at": done,
            "commit": run_info["commit"],
            "device": torch.cuda.get_device_name(0)
            if trainer.strategy.root_device.type == "cuda"
            else f"cpu ({os.cpu_count()} cores, {torch.get_num_threads()} threads)",
        }
        OmegaConf.save(OmegaConf.create(summary), out_dir / "summary.yaml")
        log.info("run folder: %s", out_dir)
        log.info("last checkpoint: %s", last.path)
        log.info("best checkpoint: %s", best_path or "none (no validation finished)")
        log.info("best average validation Euler error: %.4f", score)
    return score


def keep_earlier(run: Path, iteration: int, cfg: DictConfig) -> None:
    """What a run continued in its own folder wrote there before, kept: the summary of a run
    that had finished (trained longer now) and a config.yaml whose settings change (the length,
    Trainer keys, where files live), each as <name>-iterNNNNNN.yaml."""
    config = run / "config.yaml"
    same = config.is_file() and OmegaConf.load(config) == OmegaConf.create(
        OmegaConf.to_container(cfg, resolve=True)
    )
    for path in (run / "summary.yaml", *([] if same else [config])):
        if path.is_file():
            kept = run / f"{path.stem}-iter{iteration:06d}.yaml"
            n = 0
            while kept.exists():  # resumed at this iteration before
                n += 1
                kept = run / f"{path.stem}-iter{iteration:06d}-{n}.yaml"
            path.rename(kept)
            log.info("kept the run's earlier %s as %s", path.name, kept.name)


@hydra_entry("train", started="config.yaml")  # refused before it is written: the folder goes
def main(cfg: DictConfig) -> float:
    try:
        score = train(cfg)
    except ck.TrainingInterrupted as err:
        log.warning("%s", err)
        raise SystemExit(128 + err.signum) from None
    except NonFiniteLossError as err:
        if HydraConfig.get().mode != RunMode.MULTIRUN:
            raise
        # In a sweep a diverged run is a result: +inf, and the study goes on (docs/cluster.md).
        log.error("run diverged, scored +inf: %s", err)
        return math.inf
    # The Optuna sweeper cannot record NaN (it would stop the study): no result is the worst.
    return math.inf if math.isnan(score) else score


if __name__ == "__main__":
    main()
