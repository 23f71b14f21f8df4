"""src.eval's work: a baseline, a trained checkpoint (tested as a MotionPredictor) or a file of
predictions (src/scoring.py) evaluated on the protocol's test windows. `evaluate` writes the
tables as results.{md,csv,json} into the run's folder; `read_results` reads results.json back
(src.plot_errors, src.report).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import lightning as L
from omegaconf import DictConfig

from src.lit.config import check
from src.lit.factory import ConfigError, build_for_evaluation, build_trainer, git_commit
from src.lit.run_folders import training_run_name
from src.reporting.published import published_for
from src.reporting.tables import ResultTable, results_from_metric
from src.scoring import score_predictions


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
    check(cfg, "eval")
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


def read_results(path: str | Path) -> dict:
    """The parsed results.json of one `python -m src.eval` run."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(
            f"results file not found: {path}. `python -m src.eval ...` writes results.json "
            "into its run folder under outputs/eval/runs/."
        )
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise ConfigError(f"{path} is not valid JSON: {err}") from err
    if not isinstance(data, dict) or "tables" not in data:
        raise ConfigError(f"{path} has no 'tables'; is it a results.json from src.eval?")
    return data
