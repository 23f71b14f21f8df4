"""The published numbers of Li et al. 2018 (Tables 1-6) and Martinez et al. 2017 (Tables 1-2),
and what the results page knows about each experiment's published references.

published_results.csv is a byte copy of the project's shared docs/published_results.csv: one
value per row, `paper,table,dataset,method,action,ms,value`, as printed in the papers (slips
included, N/A cells omitted); an "average" row is the paper's own, over that table's actions.
Paper keys "li2018", "martinez2017"; method keys e.g. "conv_s2s" (Li's "Ours"), "rrnn"
(Martinez's residual model retrained by Li), "zero_velocity", "residual_sup_ma".
"""

from __future__ import annotations

import functools
from importlib import resources

import pandas as pd


class ReportingError(ValueError):
    """A published-results lookup or a result table got inconsistent or unknown input."""


@functools.cache
def published_frame() -> pd.DataFrame:
    """Every published cell, one row each: paper, table, dataset, method, action, ms, value."""
    with resources.files("src.reporting").joinpath("published_results.csv").open() as fh:
        return pd.read_csv(fh)


def find_published(dataset: str, method: str) -> list[tuple[str, int]]:
    """The (paper, table) pairs that report `method` on `dataset`, sorted; [] if none."""
    f = published_frame()
    rows = f[(f.dataset == dataset) & (f.method == method)]
    return sorted({(str(p), int(t)) for p, t in zip(rows.paper, rows.table, strict=True)})


def published_datasets() -> frozenset[str]:
    """The datasets the papers published numbers for ("h36m", "cmu")."""
    return frozenset(published_frame().dataset)


def published_table(
    paper: str, table: int | None, dataset: str, method: str
) -> dict[str, dict[int, float]]:
    """Published values {action: {ms: value}} of one method in one paper; table=None merges
    the paper's tables (Li's Tables 1 and 2 cover the 15 H3.6M actions). A cell printed with
    two values in the merged tables raises: pick the table then."""
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
    for action, ms, value in zip(rows.action, rows.ms, rows.value, strict=True):
        out.setdefault(action, {})[int(ms)] = float(value)
    return out


def published_for(ref: dict | None, dataset: str) -> tuple[dict | None, str | None]:
    """(values {action: {ms: value}}, "<paper> <method>") of a model config's `published` entry
    ({paper, method[, table]}, or one such entry per dataset) for results on `dataset`;
    (None, None) where no paper has numbers for it. Synthetic data, in the H3.6M format, never
    gets H3.6M's numbers: a published value stands only beside results on its own dataset."""
    if not ref or dataset not in published_datasets():
        return None, None
    ref = ref.get(dataset, ref)
    if not isinstance(ref, dict) or "paper" not in ref:
        return None, None
    try:
        table = published_table(ref["paper"], ref.get("table"), dataset, ref["method"])
    except ReportingError:
        return None, None
    return table, f"{ref['paper']} {ref['method']}"


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
    """{action: why} for the `actions` whose published values under `label` ("<paper>
    <method>") include a known slip of the paper."""
    slips = KNOWN_SLIPS.get(tuple(label.split(" ", 1)), {}) if label and " " in label else {}
    return {a: slips[a] for a in actions if a in slips}


PAPERS = {"li2018": "Li et al.", "martinez2017": "Martinez et al."}
# Published numbers of experiments whose model config names the full model's: the ablations
# of Li's Tables 5 and 6 (averages only), and Figure 4's rows, printed without numbers (None).
EXPERIMENT_PUBLISHED: dict[str, dict | None] = {
    "li2018_h36m_no_long_term": {
        "paper": "li2018",
        "table": 5,
        "method": "conv_s2s_without_long_term",
    },
    "li2018_h36m_kernel_4x4": {"paper": "li2018", "table": 6, "method": "kernel_4x4"},
    "li2018_h36m_kernel_7x2": {"paper": "li2018", "table": 6, "method": "kernel_7x2"},
    **{f"li2018_h36m_{c}": None for c in ("C5", "C10", "C5_no_adv", "C10_no_adv", "C20_no_adv")},
}
# Other papers' numbers for the same model on the same data: Li et al. retrained Martinez et
# al.'s residual GRU with Martinez's code (row "RRNN" of their Tables 1-2).
ALSO_PUBLISHED: dict[tuple[str, str], list[dict]] = {
    ("martinez2017 residual_sup_ma", "h36m"): [
        {
            "paper": "li2018",
            "method": "rrnn",
            "about": "Li et al.'s retraining of the same model, row RRNN of their Tables 1-2",
        }
    ],
}
# What was compared with an experiment's reference code, for the diagnosis of a row that misses
# its target (facts: the shared docs/protocol.md).
REFERENCE_CODE_CHECKED: dict[str, str] = {
    "li2018_cmu": "Every setting was checked against Li et al.'s reference code: the actions "
    "trained together, iterations, batch, learning rate and its decay, window lengths, the "
    "dimensions kept, the normalisation rule, VALID padding, test-window selection and seed, "
    "the Euler error"
}
