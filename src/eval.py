"""`python -m src.eval`: a baseline, a trained checkpoint or a file of predictions from any code
(src/scoring.py) evaluated on the protocol's test windows; the tables are printed and written as
results.{md,csv,json} and as long rows (results_long.csv) into the run's folder
(src/results.py). Usage: `--help`, README.
"""

from src.cli import hydra_entry
from src.results import evaluate

# Refused (a bad checkpoint, missing data): as with src.train, its folder goes.
main = hydra_entry("eval", started="results.json")(evaluate)

if __name__ == "__main__":
    main()
