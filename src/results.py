"""src.eval's work: a baseline, a trained checkpoint or a file of predictions (src/scoring.py),
tested as a MotionPredictor; the tables in src/reporting/tables.py's format."""

import json
import time
from pathlib import Path

import lightning as L
from omegaconf import DictConfig

from src.config import check
from src.data.files import atomic_write
from src.lit.factory import build_for_evaluation, build_trainer, git_commit
from src.lit.run_folders import training_run_name
from src.reporting.published import published_for
from src.reporting.tables import result_table, results_from_metric, table_markdown, tables_csv
from src.scoring import score_predictions


def build_tables(module, dm, model_cfg: dict, dataset: str) -> list[dict]:
    """The Euler and MPJPE tables of an evaluation on `dataset` (the data config's name:
    published numbers stand only beside results on their own dataset, never on "synthetic")."""
    published, label = published_for(model_cfg.get("published"), dataset)
    where = f"{model_cfg['name']} on {dataset} ({dm.eval_protocol} protocol, "
    where += f"{len(dm.eval_windows)} windows)"
    mm = "mm" if dm.dataset_name == "h36m" else "skeleton units"
    tables = []
    for metric, title, unit in (
        ("euler", "Euler-angle error", "rad"),
        ("mpjpe", "Mean per-joint position error", mm),
    ):
        values = results_from_metric(
            module.last_results[metric], dm.actions, dm.frame_ms, dm.absent_actions
        )
        paper = (published, label) if metric == "euler" else (None, None)
        args = (dm.actions, module.horizons, values, dm.absent_actions, *paper)
        # The model's untrained actions (its checkpoint's), a baseline's: this copy's.
        untrained = module.untrained_actions
        tables.append(result_table(f"{title}: {where}", metric, unit, *args, untrained=untrained))
    return tables


def evaluate(cfg: DictConfig) -> dict:
    check(cfg, "eval")
    L.seed_everything(cfg.seed, workers=True)
    start = time.perf_counter()
    dm, module = (score_predictions if cfg.get("predictions") else build_for_evaluation)(cfg)
    model_cfg = module.run_info["config"]["model"]
    dataset = module.run_info["config"]["data"]["name"]
    trainer = build_trainer(
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
    markdown = "\n\n".join(table_markdown(t) for t in tables)
    (out_dir / "results.md").write_text(markdown + "\n")
    (out_dir / "results.csv").write_text(tables_csv(tables))
    result = {"provenance": provenance, "tables": tables}
    # Last and whole or not at all: its presence marks the folder complete (src/eval.py's
    # started=), which a Ctrl-C or a refusal leaves in place.
    atomic_write(out_dir / "results.json", lambda tmp: tmp.write_text(json.dumps(result, indent=2)))
    print(f"{markdown}\n\nwritten to {out_dir}")
    return result
