"""Evaluate a baseline or a trained checkpoint on the protocol's test windows.

    python -m src.eval model=zero_velocity data=h36m
    python -m src.eval model=running_avg_2 data=h36m data.allow_partial=true
    python -m src.eval ckpt_path=outputs/train/runs/<run>/<time>/checkpoints/last.ckpt
    python -m src.eval ckpt_path=... protocol=random      (256 windows per action)
    python -m src.eval predictions=preds.npz data=h36m    (predictions from any code, of the
                                                           windows src.export_windows wrote)

Prints the per-action tables in the papers' layout (Euler-angle error, then MPJPE) with the
published value beside ours where a paper gives one, and writes results.{md,csv,json} into the
run's own folder under outputs/eval/.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import hydra
import lightning as L
from omegaconf import DictConfig, OmegaConf

from src.lit.checkpoints import module_from_checkpoint, read_checkpoint
from src.lit.factory import (
    ConfigError,
    build_datamodule,
    build_module,
    git_commit,
    register_resolvers,
)
from src.lit.runs import nothing_left_if_refused
from src.lit.validation import hydra_entry, validate_eval_config
from src.reporting.published import published_for
from src.reporting.tables import ResultTable, results_from_metric
from src.scoring import score_predictions

log = logging.getLogger(__name__)
register_resolvers()


def load_for_eval(cfg: DictConfig):
    """(datamodule, module, description) for a checkpoint or a baseline config."""
    if cfg.ckpt_path:
        ckpt = read_checkpoint(cfg.ckpt_path)
        dm, module = module_from_checkpoint(ckpt, cfg, cfg.ckpt_path)
        saved = ckpt["motion"]["config"]
        return dm, module, saved["model"], saved["data"]["name"]
    if cfg.get("model") is None or cfg.get("data") is None:
        raise ConfigError(
            "say what to evaluate: a baseline with model=zero_velocity|running_avg_2|"
            "running_avg_4 and data=h36m|cmu, or a trained model with ckpt_path=..."
        )
    data_cfg = cfg.data.copy()
    if cfg.get("protocol"):
        data_cfg.eval_protocol = cfg.protocol
    dm = build_datamodule(data_cfg)
    dm.prepare_data()
    dm.setup("validate")
    module = build_module(cfg, dm, run_info={"commit": git_commit()})
    if module.trainable:
        raise ConfigError(
            f"model={cfg.model.name} is a trainable network and no ckpt_path was given; the "
            "numbers of an untrained network mean nothing. Train it with `python -m src.train "
            f"model={cfg.model.name} ...` and pass ckpt_path=<its checkpoint>."
        )
    return dm, module, OmegaConf.to_container(cfg.model, resolve=True), cfg.data.name


def training_run_name(ckpt_path: str | Path) -> str:
    """The name of the training run a checkpoint belongs to: `run_name` of the run's
    config.yaml (<run>/checkpoints/<file>.ckpt), else the run folder's name (its parent's when
    the folder is a timestamp)."""
    path = Path(ckpt_path)
    run = path.parent.parent if path.parent.name == "checkpoints" else path.parent
    config = run / "config.yaml"
    if config.is_file():
        try:
            name = OmegaConf.load(config).get("run_name")
        except Exception:  # noqa: BLE001 (an unreadable config only loses the name)
            name = None
        if isinstance(name, str) and name:
            return name
    stamp = run.name.replace("-", "").replace("_", "")
    return run.parent.name if stamp.isdigit() else run.name


def build_tables(module, dm, model_cfg: dict, dataset: str) -> list[ResultTable]:
    """The Euler and MPJPE tables of an evaluation on `dataset` (the data's own name, e.g.
    "synthetic": the published numbers appear only beside results on the paper's dataset)."""
    published, label = published_for(model_cfg.get("published"), dataset)
    tables = []
    for metric, title, unit in (
        ("euler", "Euler-angle error", "rad"),
        ("mpjpe", "Mean per-joint position error", "mm" if dm.dataset_name == "h36m" else "units"),
    ):
        values = results_from_metric(
            module.last_results[metric], dm.actions, dm.frame_ms, dm.absent_actions
        )
        tables.append(
            ResultTable(
                title=f"{title}: {model_cfg['name']} on {dataset} "
                f"({dm.eval_protocol} protocol, {len(dm.eval_windows)} windows)",
                metric=metric,
                unit=unit,
                actions=list(dm.actions),
                horizons_ms=list(module.horizons),
                values=values,
                absent=dict(dm.absent_actions),
                published=published if metric == "euler" else None,
                published_label=label,
            )
        )
    return tables


def evaluate(cfg: DictConfig) -> dict:
    validate_eval_config(cfg)
    L.seed_everything(cfg.seed, workers=True)
    start = time.perf_counter()
    if cfg.get("predictions"):  # a file of predictions from any code, src/scoring.py
        dm, module, model_cfg, dataset = score_predictions(cfg)
    else:
        dm, module, model_cfg, dataset = load_for_eval(cfg)
        trainer: L.Trainer = hydra.utils.instantiate(
            cfg.trainer, logger=False, callbacks=[], enable_checkpointing=False, max_epochs=1
        )
        trainer.test(module, datamodule=dm, verbose=False)
    tables = build_tables(module, dm, model_cfg, dataset)

    out_dir = Path(cfg.paths.output_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    provenance = {
        "model": model_cfg["name"],
        "run_name": training_run_name(cfg.ckpt_path) if cfg.ckpt_path else model_cfg["name"],
        "dataset": dataset,
        "checkpoint": str(cfg.ckpt_path) if cfg.ckpt_path else None,
        "predictions": str(cfg.predictions) if cfg.get("predictions") else None,
        "eval_protocol": dm.eval_protocol,
        "windows": len(dm.eval_windows),
        "missing_files": list(dm.missing_files),
        "commit": git_commit(),
        "wall_time_s": round(time.perf_counter() - start, 1),
    }
    markdown = "\n\n".join(t.to_markdown() for t in tables)
    (out_dir / "results.md").write_text(markdown + "\n")
    # One header for both tables: a second one would be read as a row of data.
    csv_text = "".join(t.to_csv(header=i == 0) for i, t in enumerate(tables))
    (out_dir / "results.csv").write_text(csv_text)
    result = {"provenance": provenance, "tables": [t.to_dict() for t in tables]}
    (out_dir / "results.json").write_text(json.dumps(result, indent=2))
    print(markdown)
    print(f"\nwritten to {out_dir}")
    return result


@hydra_entry("eval")
def main(cfg: DictConfig) -> None:
    # Refused (a bad checkpoint, missing data): as with src.train, its folder goes.
    with nothing_left_if_refused("results.json"):
        evaluate(cfg)


if __name__ == "__main__":
    main()
