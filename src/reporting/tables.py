"""The one markdown writer of every table, number formats, the published average over a set of
actions, and reading src.eval's results (results.json, results_long.csv: LONG rows)."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from src.config import ConfigError

AVERAGE = "average"
RIGHT = ("n", "iterations", "seed", "best at", "wall time")
# An evaluation as long rows (results_long.csv, a record in docs/runs): a value per run,
# protocol, checkpoint ("best", "last", "validation"), metric, action ("average" for a
# validation) and horizon; an absent action's rows hold no value and the reason.
LONG = ["run", "experiment", "dataset", "seed", "iterations", "protocol", "checkpoint"]
LONG += ["metric", "action", "horizon", "value", "absent"]


def markdown(rows, columns=None) -> str:
    """A GitHub table, cells as written; the columns in ms and the counts right-aligned."""
    frame = pd.DataFrame(rows, columns=columns)
    align = ["right" if str(c).endswith(" ms") or c in RIGHT else "left" for c in frame.columns]
    return frame.to_markdown(index=False, disable_numparse=True, colalign=align)


def fmt(value: float | None, decimals: int = 2) -> str:
    return "-" if value is None or value != value else f"{value:.{decimals}f}"


def same_set_average(published, actions, horizons_ms) -> dict[int, float]:
    """The published values averaged over our `actions`, where every one of them has a value."""
    out = {}
    for ms in horizons_ms if published and actions else ():
        cells = [published.get(a, {}).get(ms) for a in actions]
        if None not in cells:
            out[int(ms)] = sum(cells) / len(cells)
    return out


def read_long(path) -> pd.DataFrame:
    # Read as text: an all-empty column would be float, which pandas 4 will not fill with "".
    frame = pd.read_csv(path, dtype={"absent": object})
    return frame.assign(absent=frame.absent.fillna(""))


def read_results(path) -> dict:
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
