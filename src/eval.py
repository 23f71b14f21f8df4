"""`python -m src.eval`: a baseline, a trained checkpoint or a file of predictions from any code
(src/scoring.py) evaluated on the protocol's test windows; the tables are printed and written as
results.{md,csv,json} into the run's folder (src/results.py). Usage: `--help`, README.
"""

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
