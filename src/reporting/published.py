"""The papers' numbers: published_results.csv (a byte copy of the shared
docs/published_results.csv: Li et al. 2018 Tables 1-6, Martinez et al. 2017 Tables 1-2, as
printed, slips included, N/A omitted), published_released.csv (table 0: HisRep's released
per-action errors on 8 and 256 windows, shared docs/hisrep.md §8) and references.json (the
papers' slips, the ablations' references, other papers' numbers of a model, what was checked
against reference code, the ablation claims).
"""

from __future__ import annotations

import contextlib
import functools
import json
from importlib import resources

import pandas as pd

DATA = resources.files("src.reporting")
REFERENCES = json.loads(DATA.joinpath("references.json").read_text())
PAPERS = REFERENCES["papers"]


class ReportingError(ValueError):
    """A published-results lookup or a result table got inconsistent or unknown input."""


@functools.cache
def published_frame() -> pd.DataFrame:
    """Every published cell, one row each: paper, table, dataset, method, action, ms, value."""
    frames = []
    for name in ("published_results.csv", "published_released.csv"):
        with DATA.joinpath(name).open() as fh:
            frames.append(pd.read_csv(fh))
    return pd.concat(frames, ignore_index=True)


def find_published(dataset: str, method: str) -> list[tuple[str, int]]:
    """The (paper, table) pairs that report `method` on `dataset`, sorted; [] if none."""
    f = published_frame()
    rows = f[(f.dataset == dataset) & (f.method == method)][["paper", "table"]].drop_duplicates()
    return sorted((str(p), int(t)) for p, t in rows.itertuples(index=False))


def published_datasets() -> frozenset[str]:
    return frozenset(published_frame().dataset)


def published_table(paper: str, table: int | None, dataset: str, method: str) -> dict:
    """{action: {ms: value}}; table=None merges the paper's tables (Li's 1 and 2: 15 actions)."""
    f = published_frame()
    rows = f[(f.paper == paper) & (f.dataset == dataset) & (f.method == method)]
    rows = rows if table is None else rows[rows.table == table]
    if rows.empty:
        known = f[["paper", "table", "dataset", "method"]].drop_duplicates()
        listing = "; ".join(f"{p} T{t} {d} {m}" for p, t, d, m in known.itertuples(index=False))
        raise ReportingError(
            f"no published numbers for paper={paper!r} table={table!r} dataset={dataset!r} "
            f"method={method!r}. Available: {listing}"
        )
    twice = rows.groupby(["action", "ms"]).value.nunique()
    if (twice > 1).any():
        action, ms = twice[twice > 1].index[0]
        raise ReportingError(
            f"{paper} {method} {dataset}: {action} at {ms} ms has two values in its tables "
            f"{sorted(set(rows.table))}; pass table= to choose"
        )
    out: dict[str, dict[int, float]] = {}
    for action, ms, value in rows[["action", "ms", "value"]].itertuples(index=False):
        out.setdefault(action, {})[int(ms)] = float(value)
    return out


def published_for(ref: dict | None, dataset: str) -> tuple[dict | None, str | None]:
    """(values, "<paper> <method>") of a model's `published` ({paper, method[, table]}, or one per
    dataset) on `dataset`, else (None, None): synthetic data never gets H3.6M's numbers."""
    ref = (ref or {}).get(dataset, ref)
    if dataset in published_datasets() and isinstance(ref, dict) and "paper" in ref:
        with contextlib.suppress(ReportingError):
            table = published_table(ref["paper"], ref.get("table"), dataset, ref["method"])
            return table, f"{ref['paper']} {ref['method']}"
    return None, None


def known_slips(label: str | None, actions: list[str]) -> dict[str, str]:
    """{action: why} of the `actions` whose values under `label` are slips of the paper."""
    slips = REFERENCES["slips"].get(label or "", {})
    return {a: slips[a] for a in actions if a in slips}
