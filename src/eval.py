"""Evaluate a baseline or a trained checkpoint on the protocol's test windows.

    python -m src.eval model=zero_velocity data=h36m
    python -m src.eval model=running_avg_2 data=h36m data.allow_partial=true
    python -m src.eval ckpt_path=outputs/train/runs/<run>/<time>/checkpoints/last.ckpt
    python -m src.eval ckpt_path=... protocol=random      (256 windows per action)
    python -m src.eval predictions=preds.npz data=h36m    (predictions from any code, of the
                                                           windows src.export_windows wrote)

Prints the per-action tables in the papers' layout (Euler-angle error, then MPJPE) with the
published value beside ours where a paper gives one, and writes results.{md,csv,json} into the
run's own folder under outputs/eval/ (src/results.py's `evaluate`).
"""

from __future__ import annotations

from omegaconf import DictConfig

from src.cli import hydra_entry
from src.lit.run_folders import nothing_left_if_refused
from src.results import evaluate


@hydra_entry("eval")
def main(cfg: DictConfig) -> None:
    # Refused (a bad checkpoint, missing data): as with src.train, its folder goes.
    with nothing_left_if_refused("results.json"):
        evaluate(cfg)


if __name__ == "__main__":
    main()
