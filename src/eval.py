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

import lightning as L
from omegaconf import DictConfig

from src.cli import hydra_entry
from src.lit.factory import build_for_evaluation, build_trainer, git_commit, register_resolvers
from src.lit.runs import nothing_left_if_refused, training_run_name
from src.lit.validation import validate_eval_config
from src.reporting.published import published_for
from src.reporting.tables import ResultTable, results_from_metric
from src.scoring import score_predictions

log = logging.getLogger(__name__)
register_resolvers()


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
        dm, module = build_for_evaluation(cfg)
        model_cfg = module.run_info["config"]["model"]
        dataset = module.run_info["config"]["data"]["name"]
        trainer: L.Trainer = build_trainer(
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
