"""The published result tables of Li et al. 2018 (Tables 1-6) and Martinez et al. 2017 (1-2).

published_results.csv is a byte copy of the project's shared docs/published_results.csv (see
published_results.md there): one value per row, `paper,table,dataset,method,action,ms,value`,
values as printed in the papers (slips included, N/A cells omitted). Some tables have an
"average" row; it is the paper's own average, over that table's actions, not recomputed.

Paper keys: "li2018", "martinez2017". Method keys, e.g. "conv_s2s" (Li's "Ours"), "rrnn"
(Martinez's residual model retrained by Li), "zero_velocity", "residual_sup_ma".
"""

import csv
import functools
import io
from importlib import resources
from typing import NamedTuple


class ReportingError(ValueError):
    """A published-results lookup or a result table got inconsistent or unknown input."""


class PublishedRow(NamedTuple):
    paper: str
    table: int
    dataset: str
    method: str
    action: str
    ms: int
    value: float


@functools.cache
def _rows() -> tuple[PublishedRow, ...]:
    text = resources.files("src.reporting").joinpath("published_results.csv").read_text()
    reader = csv.DictReader(io.StringIO(text))
    return tuple(
        PublishedRow(
            r["paper"],
            int(r["table"]),
            r["dataset"],
            r["method"],
            r["action"],
            int(r["ms"]),
            float(r["value"]),
        )
        for r in reader
    )


def load_published() -> list[PublishedRow]:
    """All published numbers, one row per table cell, in file order."""
    return list(_rows())


def find_published(dataset: str, method_key: str) -> list[tuple[str, int]]:
    """The (paper, table) pairs that report `method_key` on `dataset`, sorted; [] if none."""
    return sorted(
        {(r.paper, r.table) for r in _rows() if (r.dataset, r.method) == (dataset, method_key)}
    )


def published_table(
    paper: str, table: int | None, dataset: str, method: str
) -> dict[str, dict[int, float]]:
    """Published values {action: {ms: value}} of one method in one paper.

    table=None merges all tables of the paper that report the method on the dataset (e.g. Li's
    Tables 1 and 2 together cover the 15 H3.6M actions). A cell reported with two different
    values in the merged tables raises; pick the table then.
    """
    rows = [
        r
        for r in _rows()
        if (r.paper, r.dataset, r.method) == (paper, dataset, method)
        and (table is None or r.table == table)
    ]
    if not rows:
        known = sorted({(r.paper, r.table, r.dataset, r.method) for r in _rows()})
        listing = "; ".join(f"{p} T{t} {d} {m}" for p, t, d, m in known)
        raise ReportingError(
            f"no published numbers for paper={paper!r} table={table!r} dataset={dataset!r} "
            f"method={method!r}. Available: {listing}"
        )
    out: dict[str, dict[int, float]] = {}
    for r in rows:
        cells = out.setdefault(r.action, {})
        if r.ms in cells and cells[r.ms] != r.value:
            raise ReportingError(
                f"{paper} {method} {dataset}: {r.action} at {r.ms} ms is {cells[r.ms]} in one "
                f"table and {r.value} in table {r.table}; pass table= to choose"
            )
        cells[r.ms] = r.value
    return out


def published_datasets() -> frozenset[str]:
    """The datasets the papers published numbers for ("h36m", "cmu")."""
    return frozenset(r.dataset for r in _rows())


def published_for(ref: dict | None, dataset: str) -> tuple[dict | None, str | None]:
    """(published values {action: {ms: value}}, label) of a model config's `published` entry,
    for results computed on `dataset`; (None, None) where no paper has numbers for it.

    `ref` is {paper, method[, table]} or one such entry per dataset ({h36m: {...}, cmu: {...}}).
    `dataset` is the name of the data the results were computed on (the data config's `name`),
    so the synthetic data, although in the H3.6M format, never gets the H3.6M numbers: a
    published value stands only beside a result on the dataset it was published for.
    """
    if not ref or dataset not in published_datasets():
        return None, None
    if dataset in ref:
        ref = ref[dataset]
    if not isinstance(ref, dict) or "paper" not in ref:
        return None, None
    try:
        table = published_table(ref["paper"], ref.get("table"), dataset, ref["method"])
    except ReportingError:
        return None, None
    return table, f"{ref['paper']} {ref['method']}"


def published_beside(table: dict, dataset: str) -> dict | None:
    """The `published` values of a result table (`ResultTable.to_dict()`, as in results.json),
    or None when the results were computed on a dataset no paper published numbers for.

    For code that prints tables from stored results (src.report): a results.json written before
    the published values were tied to the dataset may carry H3.6M numbers beside synthetic-data
    results; this drops them."""
    if dataset not in published_datasets():
        return None
    return table.get("published")


# Cells the shared notes (docs/published_results.md) call slips of the paper, kept as printed:
# (paper, method) -> {action: why}. A published average that includes one is flagged, not fixed.
KNOWN_SLIPS: dict[tuple[str, str], dict[str, str]] = {
    ("li2018", "lstm3lr"): {"smoking": "Li Table 1 repeats SRNN's smoking row"},
    ("martinez2017", "residual_sup_ma"): {
        "smoking": "Martinez Table 1's smoking row repeats the eating row",
        "phoning": "Martinez Table 2's phoning row (0.23 0.43 0.69 0.82 at 80-400 ms) is a third "
        "to a half of Li et al.'s retraining of the same model (RRNN, Li Table 2: 0.62 1.10 "
        "1.54 1.70) and of Li's own model (0.59 1.13 1.51 1.65); most likely a slip",
    },
    ("martinez2017", "zero_velocity"): {
        "greeting": "Martinez Table 2's greeting and phoning rows are equal and neither matches "
        "what the protocol gives on the data",
        "phoning": "Martinez Table 2's phoning row repeats greeting",
    },
    ("martinez2017", "residual_unsup_ma"): {
        "sitting": "Martinez Table 2's 80 ms average disagrees with its rows (sitting is the "
        "likely bad cell)"
    },
}


def known_slips(label: str | None, actions: list[str]) -> dict[str, str]:
    """{action: why} for the `actions` whose published values under `label` ("<paper> <method>",
    as published_for returns it) include a known slip of the paper."""
    if not label or " " not in label:
        return {}
    paper, method = label.split(" ", 1)
    slips = KNOWN_SLIPS.get((paper, method), {})
    return {a: slips[a] for a in actions if a in slips}
