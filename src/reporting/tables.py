"""An evaluation's result table in the papers' layout (rows: actions and their average, columns:
horizons in ms), as src.eval writes it to results.{json,md,csv}, and the one markdown writer
of every table the project prints.

A table is the dict stored in results.json: `values` holds every evaluated action, `absent`
every other one with the reason (e.g. S5 files missing from a partial data copy), printed as
"absent", never as 0 or NaN. The average is over the evaluated actions only (protocol §4.1
step 6); beside it stands the published average recomputed over the same actions (like for
like when some are absent), and below it the paper's average as printed, over all of its own.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import pandas as pd
from torch import Tensor

from src.lit.factory import ConfigError
from src.metrics.euler_error import horizon_frame_indices
from src.reporting.published import ReportingError

AVERAGE = "average"
AS_PRINTED = "average_as_printed"


def markdown(frame: pd.DataFrame) -> str:
    """A frame as a GitHub table: cells as written (no number parsing), numbers right-aligned
    (the columns named in ms and counts)."""
    right = [
        str(c).endswith(" ms") or c in ("n", "iterations", "seed", "best at", "wall time")
        for c in frame.columns
    ]
    return frame.to_markdown(
        index=False, disable_numparse=True, colalign=["right" if r else "left" for r in right]
    )


def fmt(value: float | None, decimals: int = 2) -> str:
    """A number at `decimals` places; '-' where there is none."""
    return (
        "-"
        if value is None or (isinstance(value, float) and math.isnan(value))
        else (f"{value:.{decimals}f}")
    )


def same_set_average(
    published: Mapping[str, Mapping[int, float]] | None,
    actions: Sequence[str],
    horizons_ms: Sequence[int],
) -> dict[int, float]:
    """Mean of the published per-action values over `actions`, at each horizon where the paper
    gives a value for every one of them: the published average over the same actions as ours
    (the papers' own averages cover all of theirs, and a data copy may lack some)."""
    out = {}
    for ms in horizons_ms if published and actions else ():
        cells = [published.get(a, {}).get(ms) for a in actions]
        if all(v is not None for v in cells):
            out[int(ms)] = sum(cells) / len(cells)
    return out


def results_from_metric(
    values: Tensor, actions: Sequence[str], frame_ms: float = 40, absent: Mapping | None = None
) -> dict[str, dict[int, float]]:
    """{action: {ms: value}} at the table horizons from a metric's compute() output (A, T),
    `absent` actions left out. An action with NaN (no windows) that is not listed as absent
    raises, so that no action silently disappears from a table; so does a listed one that has
    values."""
    absent = dict(absent or {})
    if values.dim() != 2 or values.shape[0] != len(actions):
        raise ReportingError(
            f"values must be (A, T) with A = len(actions) = {len(actions)}, got "
            f"{tuple(values.shape)}"
        )
    horizons = horizon_frame_indices(frame_ms, values.shape[1])
    out = {}
    for action, row in zip(actions, values.detach().double().cpu().tolist(), strict=True):
        has_values = not any(math.isnan(v) for v in row)
        if action in absent and has_values:
            raise ReportingError(
                f"action {action!r} is listed as absent ({absent[action]}) but has values"
            )
        if action not in absent and not has_values:
            raise ReportingError(
                f"action {action!r} has no evaluated windows (NaN); pass it in absent with the "
                "reason (e.g. which data files are missing)"
            )
        if has_values:
            out[action] = {ms: row[k] for ms, k in horizons.items()}
    return out


def result_table(
    title: str,
    metric: str,
    unit: str,
    actions: Sequence[str],
    horizons_ms: Sequence[int],
    values: Mapping[str, Mapping[int, float]],
    absent: Mapping[str, str],
    published: Mapping[str, Mapping[int, float]] | None = None,
    published_label: str | None = None,
) -> dict:
    """The table as results.json holds it (horizons as text keys), after checking that every
    action is either evaluated, with a finite value at each horizon, or absent with a reason."""
    horizons = [int(ms) for ms in horizons_ms]
    if not horizons:
        raise ReportingError(f"{title}: no horizons; the model predicts too few frames")
    if set(values) | set(absent) != set(actions) or set(values) & set(absent):
        raise ReportingError(
            f"{title}: each of the actions {list(actions)} must be in exactly one of values and "
            "absent (with a reason), and nothing else"
        )
    for action, row in values.items():
        if not all(ms in row and math.isfinite(row[ms]) for ms in horizons):
            raise ReportingError(
                f"{title}: {action!r} has no finite value at every horizon; list it in absent "
                "with a reason instead"
            )
    evaluated = [a for a in actions if a in values]
    n = len(evaluated) or 1  # no action evaluated: no average
    average = {ms: sum(values[a][ms] for a in evaluated) / n for ms in horizons}
    same = same_set_average(published, evaluated, horizons)

    def text_keys(row: Mapping) -> dict[str, float]:
        return {str(ms): float(v) for ms, v in row.items()}

    return {
        "title": title,
        "metric": metric,
        "unit": unit,
        "decimals": 1 if unit == "mm" else 2,
        "actions": list(actions),
        "horizons_ms": horizons,
        "values": {a: text_keys(values[a]) for a in evaluated},
        "absent": dict(absent),
        "average": {"actions": evaluated, "values": text_keys(average)} if evaluated else None,
        "published": None if published is None else {a: text_keys(r) for a, r in published.items()},
        "published_label": published_label if published is not None else None,
        "published_same_set": None if published is None else text_keys(same),
    }


def table_frame(table: Mapping) -> pd.DataFrame:
    """The table long: action, ms, value ("absent" where absent), published, note; then the
    average (published: the same-set average) and the paper's as printed."""
    published = table.get("published") or {}
    rows = []
    for action in table["actions"]:
        for ms in map(str, table["horizons_ms"]):
            value = table["values"].get(action, {}).get(ms, "absent")
            pub = published.get(action, {}).get(ms)
            rows.append((action, ms, value, pub, table["absent"].get(action, "")))
    if table["average"]:
        covered = table["average"]["actions"]
        note = f"mean over the {len(covered)} evaluated actions ({', '.join(covered)})"
        same = table.get("published_same_set") or {}
        for ms, value in table["average"]["values"].items():
            rows.append((AVERAGE, ms, value, same.get(ms), note))
        n = len(set(published) - {AVERAGE})
        scope = f"the paper's own average, over all {n or 'of its'} actions"
        printed = published.get(AVERAGE, {})
        for ms in map(str, table["horizons_ms"]):
            if ms in printed:
                rows.append((AS_PRINTED, ms, "", printed[ms], scope))
    frame = pd.DataFrame(rows, columns=["action", "ms", "value", "published", "note"])
    return frame.assign(ms=frame.ms.astype(int), metric=table["metric"])


def table_markdown(table: Mapping) -> str:
    """The table as results.md shows it: ours (published) per cell, absent actions with a
    numbered footnote for their reason, the average over the evaluated actions."""
    frame, decimals = table_frame(table), table.get("decimals", 2)
    has_published = table.get("published") is not None
    reasons = list(dict.fromkeys(r for r in table["absent"].values()))

    def cell(row) -> str:
        if row.value == "absent" or row.value == "":
            return row.value or fmt(row.published, decimals)
        text = f"{row.value:.{decimals}f}"
        return f"{text} ({fmt(row.published, decimals)})" if has_published else text

    def label(action: str) -> str:
        if action in table["absent"]:
            return f"{action} [{reasons.index(table['absent'][action]) + 1}]"
        names = {AVERAGE: f"**{AVERAGE}**", AS_PRINTED: "published average, as printed"}
        return names.get(action, action)

    frame = frame.assign(cell=[cell(r) for r in frame.itertuples()], action=frame.action.map(label))
    wide = frame.pivot(index="action", columns="ms", values="cell")
    wide = wide.reindex(list(dict.fromkeys(frame.action)))
    wide.columns = [f"{ms} ms" for ms in wide.columns]
    lines = [f"**{table['title']}**: {table['metric']} ({table['unit']})", ""]
    lines += [markdown(wide.reset_index()), ""]
    if has_published:
        lines.append(
            f"- Cells: ours (published: {table.get('published_label') or 'published'}); '-' "
            "where the paper has no number. Beside our average: the paper's values averaged "
            "over the same evaluated actions, like for like."
        )
    average = table["average"]
    lines.append(
        f"- Average: mean over the {len(average['actions'])} evaluated actions "
        f"({', '.join(average['actions'])})."
        if average
        else "- Average: no action was evaluated, so there is no average."
    )
    for k, reason in enumerate(reasons, 1):
        who = [a for a in table["actions"] if table["absent"].get(a) == reason]
        lines.append(f"- [{k}] absent ({', '.join(who)}): {reason}")
    return "\n".join(lines) + "\n"


def tables_csv(tables: Sequence[Mapping]) -> str:
    """The tables as one long CSV, one row per action and horizon: metric, action, ms, value,
    published, note, values at full precision."""
    frame = pd.concat([table_frame(t) for t in tables])
    return frame[["metric", "action", "ms", "value", "published", "note"]].to_csv(index=False)


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
