"""Published numbers, evaluation tables (src.eval's results.{json,md,csv}) and the long table of
the report: lookups against the papers, layout, absent actions, mean ± std over seeds."""

import csv
import io
import json
import math
import os
from pathlib import Path

import pandas as pd
import pytest
import torch

from src.reporting import published as published_module
from src.reporting.frame import Results
from src.reporting.groups import group_runs
from src.reporting.page import per_action_csv
from src.reporting.published import (
    ReportingError,
    find_published,
    published_frame,
    published_table,
)
from src.reporting.tables import AVERAGE, LONG, same_set_average
from src.results import long_rows, result_table, results_from_metric, table_markdown, tables_csv

PACKAGED_CSV = Path(__file__).parents[1] / "src" / "reporting" / "published_results.csv"
# The 11 H3.6M actions this data copy can evaluate (the test files of the other 4 are missing).
ELEVEN = ["walking", "eating", "smoking", "greeting", "phoning", "posing", "purchases",
          "sitting", "takingphoto", "walkingdog", "walkingtogether"]  # fmt: skip

# Li et al. 2018, Table 2, "Ours" (as printed).
LI_T2_CONV = {
    "directions": (0.39, 0.60, 0.80, 0.91, 1.45),
    "greeting": (0.51, 0.82, 1.21, 1.38, 1.72),
    "phoning": (0.59, 1.13, 1.51, 1.65, 1.81),
    "posing": (0.29, 0.60, 1.12, 1.37, 2.65),
    "purchases": (0.63, 0.91, 1.19, 1.29, 2.52),
    "sitting": (0.39, 0.61, 1.02, 1.18, 1.67),
    "sittingdown": (0.41, 0.78, 1.16, 1.31, 2.06),
    "takingphoto": (0.23, 0.49, 0.88, 1.06, 1.40),
    "waiting": (0.30, 0.62, 1.09, 1.30, 2.50),
    "walkingdog": (0.59, 1.00, 1.32, 1.44, 1.92),
    "walkingtogether": (0.27, 0.52, 0.71, 0.74, 1.28),
    "average": (0.38, 0.68, 1.01, 1.13, 1.77),
}
LI_MS = (80, 160, 320, 400, 1000)


# --- published numbers -----------------------------------------------------------------------


def test_packaged_csv_is_a_byte_copy_of_the_shared_one():
    candidates = [Path("/work/shared/docs/published_results.csv")]
    if os.environ.get("MOTION_ARCHIVES"):
        archives = Path(os.environ["MOTION_ARCHIVES"])
        candidates.insert(0, archives.parent / "docs" / "published_results.csv")
    shared = next((p for p in candidates if p.is_file()), None)
    if shared is None:
        pytest.skip("the shared docs/published_results.csv is not on this machine")
    assert PACKAGED_CSV.read_bytes() == shared.read_bytes()


def test_published_rows_are_typed():
    rows = published_frame()
    assert len(rows) == 771 + 180  # data lines of the two csv files
    assert list(rows.columns) == ["paper", "table", "dataset", "method", "action", "ms", "value"]
    first = rows.iloc[0]
    assert tuple(first) == ("li2018", 1, "h36m", "erd", "walking", 80, 0.93)


def test_martinez_table1_zero_velocity_walking():
    table = published_table("martinez2017", 1, "h36m", "zero_velocity")
    assert table["walking"] == {80: 0.39, 160: 0.68, 320: 0.99, 400: 1.15}
    assert set(table) == {"walking", "eating", "smoking", "discussion"}  # no "average" row


def test_hisreps_released_values_average_to_the_files_own_average_rows():
    """The 15 actions' transcribed cells give the result files' average rows (shared
    docs/hisrep.md §8, 8 / 256 windows) and the 11-action averages of this data copy."""
    ms = [80, 160, 320, 400, 560, 1000]
    rows = {
        (windows, over): [sum(t[a][m] for a in actions) / len(actions) for m in ms]
        for windows, method in ((8, "hisrep"), (256, "hisrep_256"))
        for t in [published_table("mao2020", None, "h36m", method)]
        for over, actions in (("15", sorted(t)), ("11", ELEVEN))
    }
    want = {
        (8, "15"): [0.272, 0.515, 0.823, 0.942, 1.142, 1.590],
        (256, "15"): [0.309, 0.545, 0.902, 1.036, 1.250, 1.651],
        (8, "11"): [0.282, 0.514, 0.830, 0.944, 1.118, 1.529],
        (256, "11"): [0.302, 0.538, 0.872, 0.995, 1.199, 1.595],
    }
    for key, values in want.items():
        assert rows[key] == pytest.approx(values, abs=0.0011), key  # cells rounded to 0.001
    assert len(published_table("mao2020", None, "h36m", "hisrep")) == 15  # no average row


def test_li_table2_conv_s2s():
    table = published_table("li2018", 2, "h36m", "conv_s2s")
    assert table == {a: dict(zip(LI_MS, v, strict=True)) for a, v in LI_T2_CONV.items()}


def test_average_rows_exist_only_where_printed():
    rows = published_frame()
    rows = rows[rows.action == "average"]
    with_average = set(zip(rows.paper, rows.table, rows.method, strict=True))
    assert ("li2018", 2, "conv_s2s") in with_average
    assert ("li2018", 4, "rrnn") in with_average
    assert not any(t == 1 for _, t, _ in with_average)


def test_table_none_merges_tables_of_a_paper():
    merged = published_table("li2018", None, "h36m", "conv_s2s")
    assert len(merged) == 16  # 15 actions (Tables 1 and 2) + Table 2's average
    assert merged["walking"] == {80: 0.33, 160: 0.54, 320: 0.68, 400: 0.73, 1000: 0.92}
    assert merged["posing"][1000] == 2.65


def test_find_published():
    assert find_published("h36m", "zero_velocity") == [("martinez2017", 1), ("martinez2017", 2)]
    assert find_published("cmu", "conv_s2s") == [("li2018", 3), ("li2018", 4)]
    assert find_published("cmu", "zero_velocity") == []


def test_unknown_lookup_lists_what_exists():
    with pytest.raises(ReportingError, match="li2018 T2 h36m conv_s2s"):
        published_table("li2018", 2, "h36m", "convs2s")


def test_conflicting_cells_raise(monkeypatch):
    import pandas as pd

    rows = pd.DataFrame(
        [("p", 1, "h36m", "m", "walking", 80, 0.5), ("p", 2, "h36m", "m", "walking", 80, 0.6)],
        columns=["paper", "table", "dataset", "method", "action", "ms", "value"],
    )
    monkeypatch.setattr(published_module, "published_frame", lambda: rows)
    with pytest.raises(ReportingError, match="pass table="):
        published_table("p", None, "h36m", "m")
    assert published_table("p", 2, "h36m", "m") == {"walking": {80: 0.6}}


# --- result tables ---------------------------------------------------------------------------


def make_table(**overrides) -> dict:
    kwargs = dict(
        title="Zero-velocity, H3.6M",
        metric="euler",
        unit="rad",
        actions=["walking", "eating", "discussion", "smoking"],
        horizons_ms=[80, 160, 320, 400],
        values={
            "walking": {80: 0.3941, 160: 0.6781, 320: 0.9861, 400: 1.1521},
            "eating": {80: 0.2711, 160: 0.4791, 320: 0.7271, 400: 0.8631},
            "smoking": {80: 0.2581, 160: 0.4831, 320: 0.9701, 400: 0.9491},
        },
        absent={"discussion": "S5 discussion_1.txt and discussion_2.txt are missing"},
        published=published_table("martinez2017", 1, "h36m", "zero_velocity"),
        published_label="martinez2017 zero_velocity",
    )
    kwargs.update(overrides)
    return result_table(**kwargs)


def test_average_is_mean_over_evaluated_actions():
    table = make_table()
    assert table["average"]["actions"] == ["walking", "eating", "smoking"]
    avg = table["average"]["values"]
    assert avg["80"] == pytest.approx((0.3941 + 0.2711 + 0.2581) / 3)
    assert avg["400"] == pytest.approx((1.1521 + 0.8631 + 0.9491) / 3)


def md_rows(md: str) -> list[str]:
    """The markdown's lines, table cells stripped of their padding."""
    return [
        " | ".join(c.strip() for c in line.strip("|").split("|")) if line.startswith("|") else line
        for line in md.splitlines()
    ]


def test_markdown_layout_with_published_and_absent():
    md = table_markdown(make_table())
    lines = md_rows(md)
    assert "action | 80 ms | 160 ms | 320 ms | 400 ms" in lines
    assert "walking | 0.39 (0.39) | 0.68 (0.68) | 0.99 (0.99) | 1.15 (1.15)" in lines
    assert "discussion [1] | absent | absent | absent | absent" in lines
    # Beside our average: Martinez's values averaged over the same 3 evaluated actions.
    assert "**average** | 0.31 (0.31) | 0.55 (0.55) | 0.89 (0.90) | 0.99 (0.99)" in lines
    assert (
        "- [1] absent (discussion): S5 discussion_1.txt and discussion_2.txt are missing" in lines
    )
    assert "mean over the 3 evaluated actions (walking, eating, smoking)" in md
    assert "martinez2017 zero_velocity" in md
    assert "nan" not in md.lower()


def test_markdown_without_published_and_mpjpe_decimals():
    values = {
        a: {ms: 12.345 for ms in (80, 160, 320, 400)} for a in ("walking", "eating", "smoking")
    }
    table = make_table(metric="mpjpe", unit="mm", published=None, values=values)
    assert table["decimals"] == 1
    assert "walking | 12.3 | 12.3 | 12.3 | 12.3" in md_rows(table_markdown(table))


def test_csv_long_format():
    rows = list(csv.DictReader(io.StringIO(tables_csv([make_table()]))))
    assert list(rows[0]) == ["metric", "action", "ms", "value", "published", "note"]
    assert {r["metric"] for r in rows} == {"euler"}
    assert len(rows) == 4 * 4 + 4  # 4 actions x 4 horizons + average
    walking80 = rows[0]
    assert (walking80["action"], walking80["ms"]) == ("walking", "80")
    assert float(walking80["value"]) == 0.3941 and float(walking80["published"]) == 0.39
    discussion = [r for r in rows if r["action"] == "discussion"]
    assert {r["value"] for r in discussion} == {"absent"}
    assert discussion[0]["published"] == "0.31"  # Martinez Table 1 has discussion
    assert "missing" in discussion[0]["note"]
    average = [r for r in rows if r["action"] == "average"]
    assert float(average[0]["value"]) == pytest.approx((0.3941 + 0.2711 + 0.2581) / 3)
    assert "walking, eating, smoking" in average[0]["note"]


def test_the_table_is_json_ready():
    d = json.loads(json.dumps(make_table()))
    assert d["values"]["walking"]["80"] == 0.3941
    assert d["absent"] == {"discussion": "S5 discussion_1.txt and discussion_2.txt are missing"}
    assert d["average"]["actions"] == ["walking", "eating", "smoking"]
    assert d["published"]["walking"]["400"] == 1.15
    assert "discussion" not in d["values"]


def test_a_model_too_short_for_any_horizon_is_refused():
    with pytest.raises(ReportingError, match="too few frames"):
        make_table(horizons_ms=[])


def test_all_absent_has_no_average():
    actions = ["walking", "eating", "discussion", "smoking"]
    table = make_table(values={}, absent={a: "no data" for a in actions})
    md = table_markdown(table)
    assert table["average"] is None and "**average**" not in md
    assert "no action was evaluated" in md


# --- from a metric's (A, T) output ----------------------------------------------------------


def test_results_from_metric_picks_protocol_horizons():
    values = torch.arange(3 * 25, dtype=torch.float64).reshape(3, 25)
    values[1] = math.nan  # action without windows
    out = results_from_metric(
        values, ["walking", "discussion", "eating"], 40, {"discussion": "gone"}
    )
    assert out == {
        "walking": {80: 1.0, 160: 3.0, 320: 7.0, 400: 9.0, 560: 13.0, 1000: 24.0},
        "eating": {80: 51.0, 160: 53.0, 320: 57.0, 400: 59.0, 560: 63.0, 1000: 74.0},
    }
    short = results_from_metric(
        values[:, :10], ["walking", "discussion", "eating"], 40, {"discussion": "gone"}
    )
    assert list(short["walking"]) == [80, 160, 320, 400]


def test_results_from_metric_refuses_silent_gaps():
    values = torch.zeros(2, 25, dtype=torch.float64)
    values[1] = math.nan
    with pytest.raises(ReportingError, match="absent"):
        results_from_metric(values, ["walking", "eating"])
    with pytest.raises(ReportingError, match="has values"):
        results_from_metric(values, ["walking", "eating"], absent={"walking": "x", "eating": "y"})
    with pytest.raises(ValueError, match="longer"):  # an action per row of values
        results_from_metric(values, ["walking"])


# --- same-set published averages ------------------------------------------------------------


def test_same_set_average_is_over_the_given_actions_only():
    published = {
        "walking": {80: 0.2, 160: 0.4},
        "eating": {80: 0.4, 160: 0.8},
        "smoking": {80: 0.9},  # no 160 ms value
        AVERAGE: {80: 9.0, 160: 9.0},  # the paper's own average is never used here
    }
    assert same_set_average(published, ["walking", "eating"], [80, 160]) == {
        80: pytest.approx(0.3),
        160: pytest.approx(0.6),
    }
    # A horizon where one of the actions has no published value has no same-set average.
    assert same_set_average(published, ["walking", "smoking"], [80, 160]) == {
        80: pytest.approx(0.55)
    }
    assert same_set_average(None, ["walking"], [80]) == {}
    assert same_set_average(published, [], [80]) == {}


def test_same_set_average_of_li_h36m_over_the_11_actions_of_this_data_copy():
    """The like-for-like comparison of issue 12: Li et al.'s H3.6M values (Tables 1 and 2)
    averaged over the 11 actions this copy can evaluate, beside the printed 15-action average."""
    published = published_table("li2018", None, "h36m", "conv_s2s")
    absent = {"discussion", "directions", "sittingdown", "waiting"}
    evaluated = [a for a in published if a != AVERAGE and a not in absent]
    assert len(evaluated) == 11
    same = same_set_average(published, evaluated, LI_MS)
    for ms in LI_MS:
        assert same[ms] == pytest.approx(sum(published[a][ms] for a in evaluated) / 11)
    # Recomputed over all 15 actions it matches the printed average up to rounding.
    everything = same_set_average(published, [a for a in published if a != AVERAGE], LI_MS)
    for ms in LI_MS:
        assert everything[ms] == pytest.approx(published[AVERAGE][ms], abs=0.006)


def test_result_table_prints_same_set_and_as_printed_averages():
    published = published_table("li2018", None, "h36m", "conv_s2s")
    values = {a: {ms: 1.0 for ms in LI_MS} for a in ("walking", "eating")}
    table = make_table(
        actions=["walking", "eating", "discussion"],
        horizons_ms=list(LI_MS),
        values=values,
        absent={"discussion": "missing"},
        published=published,
        published_label="li2018 conv_s2s",
    )
    same = same_set_average(published, ["walking", "eating"], LI_MS)
    lines = md_rows(table_markdown(table))
    average = next(line for line in lines if line.startswith("**average**"))
    assert average == "**average** | " + " | ".join(f"1.00 ({same[ms]:.2f})" for ms in LI_MS)
    printed = next(line for line in lines if line.startswith("published average, as printed"))
    assert printed.endswith(" | ".join(f"{published[AVERAGE][ms]:.2f}" for ms in LI_MS))
    assert table["published_same_set"] == {str(ms): pytest.approx(same[ms]) for ms in LI_MS}
    rows = list(csv.DictReader(io.StringIO(tables_csv([table]))))
    avg80 = next(r for r in rows if (r["action"], r["ms"]) == ("average", "80"))
    assert float(avg80["published"]) == pytest.approx(same[80])
    printed80 = next(r for r in rows if (r["action"], r["ms"]) == ("average_as_printed", "80"))
    assert float(printed80["published"]) == published[AVERAGE][80]
    assert "over all 15 actions" in printed80["note"]  # the paper's, not our 2

    # A horizon the paper has no number at (560 ms): '-', as the footnote says, in every row.
    horizons = sorted([*LI_MS, 560])
    values = {a: {ms: 1.0 for ms in horizons} for a in ("walking", "eating")}
    wider = make_table(
        actions=["walking", "eating"], horizons_ms=horizons, values=values, absent={},
        published=published, published_label="li2018 conv_s2s",
    )  # fmt: skip
    rows = {line.split(" | ")[0]: line.split(" | ")[1:] for line in md_rows(table_markdown(wider))}
    assert rows["walking"][4] == "1.00 (-)" and rows["published average, as printed"][4] == "-"


# --- the long table: mean ± std over seeds ---------------------------------------------------


def seed_runs(offsets) -> list[dict]:
    """Runs of one configuration whose seed k has walking and eating at the values below."""
    runs = []
    for seed, offset in enumerate(offsets, 1):
        values = {
            "walking": {80: 0.30 + offset, 160: 0.50 + offset},
            "eating": {80: 0.20 + 2 * offset, 160: 0.40},
        }
        table = make_table(
            actions=["walking", "eating", "discussion"],
            horizons_ms=[80, 160],
            values=values,
            absent={"discussion": "missing"},
            published=None,
        )
        config = {"run_name": "m", "seed": seed, "data": {"name": "synthetic"}}
        rows = [long_rows([table], protocol="srnn", checkpoint=s) for s in ("best", "last")]
        rows = pd.concat(rows, ignore_index=True)
        runs.append({"config": config, "seed": seed, "path": f"r{seed}", "rows": rows})
    return runs


def test_each_cell_is_mean_and_sample_std_over_the_seeds():
    results = Results(group_runs(seed_runs((0.0, 0.02, 0.04))))
    f = results.frame[(results.frame.checkpoint == "best") & results.frame.value.notna()]
    cells = f.groupby(["action", "horizon"]).value.agg(["mean", "std"])
    assert cells.loc[("walking", 80), "mean"] == pytest.approx(0.32)
    assert cells.loc[("walking", 80), "std"] == pytest.approx(0.02)  # n - 1 denominator
    assert cells.loc[("eating", 80), "std"] == pytest.approx(0.04)
    assert cells.loc[("eating", 160), "std"] == 0
    rows = list(csv.DictReader(io.StringIO(per_action_csv(results, "srnn", "euler"))))
    walking = next(r for r in rows if (r["checkpoint"], r["action"]) == ("best", "walking"))
    assert walking["n"] == "3" and float(walking["80 ms"]) == pytest.approx(0.32)
    assert float(walking["80 ms std"]) == pytest.approx(0.02)
    # The average row: mean and std of the per-seed averages (0.25, 0.28, 0.31 at 80 ms).
    mean, std, n = results.average(results.groups[0], "srnn", "best")[80]
    assert (mean, std, n) == (pytest.approx(0.28), pytest.approx(0.03), 3)
    assert results.spread(results.groups[0], "srnn", "best")[80] == pytest.approx(0.06)
    # Absent actions are in the long table, without a value and with their reason.
    frame = results.frame
    absent = frame[frame.action == "discussion"]
    assert absent.value.isna().all() and set(absent.absent) == {"missing"}


def test_an_average_over_given_actions_needs_every_one_of_them():
    """The same-set comparisons and the zero-velocity clause average over a given set of actions:
    none where one of them has no value (discussion is absent in every seed)."""
    results = Results(group_runs(seed_runs((0.0, 0.02, 0.04))))
    group = results.groups[0]
    assert results.means(group, "srnn", "best", actions=["walking"])[80] == pytest.approx(0.32)
    assert results.means(group, "srnn", "best", actions=["walking", "eating"])[160] == (
        pytest.approx(0.46)
    )
    assert results.means(group, "srnn", "best", actions=["walking", "discussion"]) == {}
    assert results.means(group, "srnn", "best", actions=[]) == {}


def test_one_seed_has_no_spread():
    results = Results(group_runs(seed_runs((0.0,))))
    mean, std, n = results.average(results.groups[0], "srnn", "best")[80]
    assert mean == pytest.approx(0.25) and n == 1 and math.isnan(std)
    assert results.spread(results.groups[0], "srnn", "best") is None


def test_seeds_evaluated_on_other_actions_are_refused():
    runs = seed_runs((0.0, 0.02))
    rows = runs[1]["rows"]
    rows.loc[rows.action == "discussion", ["value", "absent"]] = [0.1, ""]
    with pytest.raises(ReportingError, match="seeds were evaluated on different actions"):
        Results(group_runs(runs))


def test_results_csv_of_eval_is_one_table_that_tells_the_metrics_apart(
    tmp_path, synthetic_data_dir
):
    """results.csv holds the Euler and the MPJPE table: read as one CSV, each row says which
    metric it is, and no header line stands among the data."""
    from src.eval import evaluate
    from tests.conftest import compose_config

    cfg = compose_config(
        "eval",
        ["model=zero_velocity", "data=synthetic", "trainer=cpu"],
        tmp_path,
        synthetic_data_dir,
    )
    result = evaluate(cfg)
    rows = list(csv.DictReader(io.StringIO((tmp_path / "results.csv").read_text())))
    assert list(rows[0]) == ["metric", "action", "ms", "value", "published", "note"]
    assert not [r for r in rows if r["action"] == "action"]
    for table in result["tables"]:
        walking = [
            r
            for r in rows
            if (r["metric"], r["action"], r["ms"]) == (table["metric"], "walking", "80")
        ]
        assert [float(r["value"]) for r in walking] == [table["values"]["walking"]["80"]]
    # results_long.csv: one row per metric, action and horizon, each value as results.json
    # holds it, absent actions without a value (none on synthetic data).
    long = pd.read_csv(tmp_path / "results_long.csv")
    assert list(long.columns) == LONG
    assert set(long.experiment) == {"zero_velocity"} and set(long.checkpoint) == {"-"}
    assert set(long.protocol) == {result["provenance"]["eval_protocol"]}
    for table in result["tables"]:
        mine = long[long.metric == table["metric"]]
        assert len(mine) == len(table["actions"]) * len(table["horizons_ms"])
        for action, ms, value in mine[["action", "horizon", "value"]].itertuples(index=False):
            assert value == table["values"][action][str(ms)]
