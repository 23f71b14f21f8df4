"""The results page's headline (one table of every trained experiment against its published
references, first on the page and in the README), the GRU judged against both published
sources, the slips of the papers, identical runs counted once, where the page is written, and
Li et al.'s ablation claims. Built from stored evaluation results, in seconds; the slow
end-to-end check is tests/test_report.py::test_report_from_a_short_run."""

import copy
import csv
import io
import re

import pytest

from src.report import main
from src.reporting.claims import claims, claims_section
from src.reporting.frame import Results
from src.reporting.groups import ABLATIONS, group_runs
from src.reporting.headline import figures, headline_table, readme_block
from src.reporting.page import averages_table, build_page, published_csv
from src.reporting.published import known_slips, published_for
from src.reporting.runs import display_root
from src.reporting.tables import AVERAGE, same_set_average
from tests.test_report import (
    ABSENT,
    MS,
    TARGETS,
    cells,
    fake_run,
    make_run,
    offset_result,
    offset_run,
    report_cfg,
    row_of,
    rows_of,
    tables,
)

EVALUATED = [
    "walking",
    "eating",
    "smoking",
    "greeting",
    "phoning",
    "posing",
    "purchases",
    "sitting",
    "takingphoto",
    "walkingdog",
    "walkingtogether",
]
EVALUATED_CLEAN = [a for a in EVALUATED if a not in ("smoking", "phoning")]
GRU = {"h36m": {"paper": "martinez2017", "method": "residual_sup_ma"}}


def gru_result(delta: float) -> dict:
    """A GRU evaluation as src.eval stores it (Martinez et al.'s values beside ours), where
    every evaluated action is Li et al.'s RRNN value + delta (1.0 where RRNN has none)."""
    published, _ = published_for(GRU, "h36m")
    rrnn, _ = published_for({"paper": "li2018", "method": "rrnn"}, "h36m")
    actions = [a for a in published if a != AVERAGE]
    values = lambda a, ms: rrnn[a].get(ms, 1.0 - delta) + delta  # noqa: E731
    return {"provenance": {"missing_files": []}, "tables": tables(values, actions, ABSENT, ref=GRU)}


def absent(run: dict, *actions: str) -> None:
    """The actions absent from the run's evaluations, as a data copy without them gives."""
    gone = run["rows"].action.isin(actions)
    run["rows"].loc[gone, ["value", "absent"]] = [float("nan"), "not in this copy"]


def zero_of(result: dict) -> dict:
    """A zero-velocity baseline whose evaluation is `result`."""
    ref = {"paper": "martinez2017", "method": "zero_velocity"}
    return {
        "label": "zero_velocity",
        "dataset": "h36m",
        "rows": rows_of({"-": {"srnn": result}}),
        "published": ref,
    }


def gru_run(seed: int, delta: float) -> dict:
    run = fake_run(seed, 0.0, 0.0, "martinez2017_res_sup")
    result = gru_result(delta)
    run["config"]["model"]["published"] = GRU
    run["rows"] = rows_of({s: {"srnn": result, "random": result} for s in ("best", "last")})
    return run


def seeded(delta: float, seed: int, run_name="li2018_h36m", dataset="h36m", absent=ABSENT):
    run = offset_run(delta, run_name, dataset, absent=absent)
    run["seed"] = run["config"]["seed"] = seed
    run["path"] = f"job{seed}/train/runs/{run_name}/2026-01-01_00-00-00"
    results = {p: offset_result(delta, dataset, absent) for p in ("srnn", "random")}
    run["rows"] = rows_of({"best": results, "last": results})
    return run


def lead_like_runs() -> list[dict]:
    """What the lead trains: li2018_h36m, li2018_cmu and martinez2017_res_sup with 3 seeds,
    the nine ablations with one."""
    runs = [seeded(d, s) for s, d in ((1, 0.0), (2, 0.01), (3, -0.01))]
    runs += [seeded(d, s, "li2018_cmu", "cmu", {}) for s, d in ((1, 0.02), (2, 0.08), (3, 0.05))]
    runs += [gru_run(s, d) for s, d in ((1, 0.0), (2, 0.004), (3, -0.003))]
    for k, name in enumerate(ABLATIONS):
        runs.append(seeded(0.01 * k, 1, name))
    return runs


# --- several references per row: the GRU against Martinez et al. and Li et al.'s RRNN -------


def head_of(runs, targets=TARGETS):
    """(results, headline table, footnotes, why-rows-miss lines) of `runs`."""
    results = Results(group_runs(runs))
    return (results, *headline_table(results, "srnn", targets, "#ablations"))


def test_the_gru_has_both_published_sources_each_with_its_same_set_gap():
    results, head, _, _ = head_of([gru_run(1, 0.0)])
    refs = results.refs[results.groups[0]]
    assert [r.key for r in refs] == ["martinez2017 residual_sup_ma", "li2018 rrnn"]
    rrnn_same = same_set_average(refs[1].published, EVALUATED, MS)
    martinez_same = results.same_set(results.groups[0], refs[0])
    # The numbers: RRNN over these 11 actions .430 .741 1.119 1.260 1.820.
    assert [round(rrnn_same[ms], 3) for ms in (80, 160, 320, 400, 1000)] == [
        0.43,
        0.741,
        1.119,
        1.26,
        1.82,
    ]
    # Martinez et al.'s same-set average leaves its slips out, and so does ours beside it.
    assert martinez_same == same_set_average(refs[0].published, EVALUATED_CLEAN, MS)
    name = "Martinez et al. residual_sup_ma, 9 actions (slips left out: smoking, phoning)"
    martinez = row_of(head, "", "", "", name)
    ours_9 = same_set_average(refs[1].published, EVALUATED_CLEAN, MS)  # ours is RRNN's + 0
    gap = round(ours_9[160], 2) - round(martinez_same[160], 2)
    assert martinez[6] == f"{martinez_same[160]:.2f} ({gap:+.2f}, {gap:+.2f})"
    assert martinez[-1] == "beyond 0.03 at 160 ms"
    rrnn = row_of(head, "", "", "", "Li et al. rrnn, 11 actions")
    assert rrnn[5].endswith("(+0.00, +0.00)") and rrnn[10].endswith("(+0.00, +0.00)")
    assert rrnn[-1] == "within 0.03"
    # Both in the averages table too, each flagged for its own slips.
    table = averages_table(results, "srnn", "euler", published=True)
    assert "(martinez2017 residual_sup_ma), same 9 actions (slips of the paper left out" in table
    assert "published (li2018 rrnn), same 11 actions " in table


def test_the_verdict_is_against_the_models_own_paper_without_its_slips():
    """Issue 53: the GRU is judged against Martinez et al.'s own table, its slips left out of
    the same-set average (named in the footnote); Li et al.'s RRNN is a second line."""
    results, head, notes, _ = head_of(
        [gru_run(s, d) for s, d in ((1, 0.0), (2, 0.004), (3, -0.003))]
    )
    verdict = results.judge(results.groups[0], "srnn", 0.03)
    assert (verdict.status, verdict.reference.key) == ("misses", "martinez2017 residual_sup_ma")
    assert verdict.missed == {"best": [160], "last": [160]}
    assert "own paper" in verdict.why and "smoking, phoning left out" in verdict.why
    assert row_of(head, "martinez2017_res_sup")[-1] == (
        "**misses**, judged against Martinez et al. residual_sup_ma¹"
    )
    assert "smoking, phoning" in notes[0] and "Li et al. rrnn" in notes[0]
    # RRNN keeps its own line, with its own comparison (ours is RRNN's values: within).
    (rrnn,) = [r for r in cells(head) if r[3].startswith("Li et al. rrnn")]
    assert rrnn[-1] == "within 0.03"
    # A model with one reference is judged against it, with no reason needed.
    single = Results(group_runs([seeded(0.0, 1)]))
    assert single.judge(single.groups[0], "srnn", 0.03).why == ("the only published source")


def test_without_a_slip_the_models_own_paper_is_the_judge():
    """Where the data copy lacks the actions that carry the slips, the GRU is judged against
    Martinez et al., its own paper."""
    run = gru_run(1, 0.0)
    absent(run, "smoking", "phoning")
    results = Results(group_runs([run]))
    verdict = results.judge(results.groups[0], "srnn", 0.03)
    assert verdict.reference.key == "martinez2017 residual_sup_ma"
    assert verdict.why == "the model's own paper" and verdict.status == "misses"


# --- the slip flag ---------------------------------------------------------------------------


def test_martinez_phoning_is_a_known_slip_flagged_where_it_enters_an_average():
    why = known_slips("martinez2017 residual_sup_ma", ["phoning"])["phoning"]
    # The evidence is the CSV's: Martinez's row against Li's retraining and Li's own model.
    for paper, method, row in (
        ("martinez2017", "residual_sup_ma", "0.23 0.43 0.69 0.82"),
        ("li2018", "rrnn", "0.62 1.10 1.54 1.70"),
        ("li2018", "conv_s2s", "0.59 1.13 1.51 1.65"),
    ):
        published, _ = published_for({"paper": paper, "method": method}, "h36m")
        assert " ".join(f"{published['phoning'][ms]:.2f}" for ms in (80, 160, 320, 400)) == row
        assert row in why
    run = gru_run(1, 0.0)
    page = build_page(Results(group_runs([run])), ["srnn"], "cmd", None, "abc", TARGETS)
    (line,) = [x for x in page.splitlines() if x.startswith("**Slips of the papers**")]
    assert "martinez2017 residual_sup_ma: smoking, phoning" in line
    rows = csv.DictReader(io.StringIO(published_csv(Results(group_runs([run])))))  # each why
    phoning = [r for r in rows if (r["method"], r["action"]) == ("residual_sup_ma", "phoning")]
    assert phoning and {r["slip"] for r in phoning} == {why}
    _, head, _, _ = head_of([run])
    assert "Martinez et al. residual_sup_ma, 9 actions (slips left out: smoking, phoning) " in head
    assert "Li et al. rrnn, 11 actions " in head  # RRNN's average has no slip
    # Without phoning among the evaluated actions, the flag names smoking only.
    absent(run, "phoning")
    assert "9 actions (slips left out: smoking) " in head_of([run])[1]


# --- the headline -----------------------------------------------------------------------------


def paragraphs(text: str) -> list[str]:
    """Prose paragraphs of markdown: blocks between blank lines, each list item on its own,
    tables aside."""
    blocks = [b for b in text.split("\n\n") if b.strip() and not b.lstrip().startswith("|")]
    return [item for b in blocks for item in re.split(r"\n(?=- )", b)]


def test_headline_first_and_readme_block_short_on_the_leads_runs(tmp_path):
    results = Results(group_runs(lead_like_runs()))
    horizon, _ = figures(results, "srnn")
    assert all(ax.get_ylim()[0] == 0 for ax in horizon.axes)  # errors against horizon from 0
    page = build_page(
        results,
        ["srnn", "random"],
        "python -m src.report ...",
        "b" * 2000,
        "abc1234",
        TARGETS,
        figures=("results_errors.png", None),
        tables="results",
    )
    lines = page.splitlines()
    first_table = next(k for k, line in enumerate(lines) if line.startswith("| experiment"))
    assert first_table < 30
    header = [c.strip() for c in lines[first_table].strip("|").split("|")]
    assert header[:6] == ["experiment", "data", "iterations", "row", "n", "80 ms"]
    assert header[-1] == "verdict"
    # One short label per experiment, the ablations in their own section.
    head = "\n".join(lines[first_table : lines.index("", first_table)])
    labels = [r[0] for r in cells(head) if r[3] == "ours, best"]
    assert labels == ["li2018_h36m", "martinez2017_res_sup", "li2018_cmu"]
    assert "![Average Euler error against horizon, ours and published](results_errors.png)" in page
    # Then, in that order: the budget, the ablations, provenance, the averages of each protocol
    # and metric, the per-action tables (CSV files), the command.
    order = [
        "**Budget.**",
        "## Ablations",
        "## Provenance",
        "## Averages: Euler-angle error (radians), 8 windows",
        "## Averages: Euler-angle error (radians), 256 windows",
        "## Averages: MPJPE",
        "## Per-action tables",
        "## Command",
    ]
    assert [page.index(h) for h in order] == sorted(page.index(h) for h in order)
    assert "(results/euler_random.csv)" in page and "(results/mpjpe_srnn.csv)" in page
    assert page.rstrip().endswith("`python -m src.report ...`")
    assert len(lines) <= 400

    block = readme_block(results, "srnn", "abc1234", TARGETS, "docs/results_errors.png")
    assert len(block.splitlines()) <= 25
    assert all(len(p) <= 300 for p in paragraphs(block)), [len(p) for p in paragraphs(block)]
    assert "![Average Euler error against horizon" in block and "b" * 50 not in block
    assert "[docs/results.md](docs/results.md)" in block and "docs/results.md#ablations" in block
    # The figure: one panel per dataset.
    assert [ax.get_title().split(":")[0] for ax in horizon.axes] == ["h36m", "cmu"]
    horizon.savefig(tmp_path / "f.png")
    assert (tmp_path / "f.png").read_bytes()[:4] == b"\x89PNG"


def test_the_zero_velocity_yardstick_is_a_row_on_the_same_actions():
    """Issue 39: the zero-velocity baseline, evaluated by the report on the same data, is the
    first yardstick a reader asks for: its average over the same actions stands in the
    headline after its dataset's experiments."""
    zero = zero_of(offset_result(0.3))
    results = Results(group_runs([seeded(0.0, 1)]), [zero])
    head, _, _ = headline_table(results, "srnn", TARGETS, None)
    row = cells(head)[-1]
    assert row[:5] == ["zero-velocity", "h36m", "-", "baseline, 11 actions", "-"]
    published, _ = published_for({"paper": "li2018", "method": "conv_s2s"}, "h36m")
    expected = sum(published[a][1000] for a in EVALUATED) / 11 + 0.3
    assert row[10] == f"{expected:.2f}"


@pytest.mark.parametrize(
    "delta, clause",
    [
        (0.0, "; no better than zero-velocity at 560 ms"),  # equal there (1.0, no published)
        (0.01, "; no better than zero-velocity at 80, 160, 320, 400, 560, 1000 ms"),
    ],
)
def test_a_row_no_better_than_zero_velocity_says_so_in_its_verdict(delta, clause):
    """Issue 53: beating zero-velocity is the papers' headline claim, so a trained row whose
    printed average is not below zero-velocity's on the same actions says where."""
    zero = zero_of(offset_result(0.01))
    results = Results(group_runs([seeded(delta, 1)]), [zero])
    head, _, _ = headline_table(results, "srnn", TARGETS, None)
    verdict = row_of(head, "li2018_h36m")[-1]
    assert verdict == "**reproduces**, judged against Li et al. conv_s2s" + clause


@pytest.mark.parametrize("n, rows", [(1, "1 trained row:"), (2, "2 trained rows:")])
def test_the_headline_counts_the_trained_ablations(n, rows):
    _, _, notes, _ = head_of([seeded(0.0, 1)] + [seeded(0.0, 1, name) for name in ABLATIONS[:n]])
    (note,) = [line for line in notes if "ablations" in line]
    assert f"Li et al.'s ablations ({rows} Tables 5 and 6, Figure 4)" in note


def test_the_page_lists_h36m_then_cmu_then_the_ablations():
    # Records are read in file-name order: li2018_cmu, li2018_h36m_C10, li2018_h36m, martinez.
    found = [
        seeded(0.0, 1, "li2018_cmu", "cmu", {}),
        seeded(0.0, 1, ABLATIONS[0]),
        seeded(0.0, 1),
        seeded(0.0, 2),
        gru_run(1, 0.0),
    ]
    results = Results(group_runs(found))
    order = ["li2018_h36m", "martinez2017_res_sup", "li2018_cmu", ABLATIONS[0]]
    assert [g.label for g in results.groups] == order
    head, _, _ = headline_table(results, "srnn", TARGETS, None)
    assert [r[0] for r in cells(head) if r[3] == "ours, best"] == order[:3]


# --- identical runs are one seed --------------------------------------------------------------


def test_a_run_and_a_sweep_job_with_the_same_config_and_seed_are_one_seed():
    """Runs of one seed (a copy, a sweep job, a killed run and its resumed segments) count
    once: the longest trained is kept with its own validation curve, the page names the
    others."""
    single = seeded(0.0, 1234)
    sweep = copy.deepcopy(single)
    sweep["path"] = "multiruns/2026-01-01/0_li2018_h36m_seed1234"
    (group,) = group_runs([single, sweep, seeded(0.01, 2)])
    assert [r["seed"] for r in group.runs] == [2, 1234]  # in seed order
    assert group.runs[1] is single  # of equals, the first given
    page = build_page(Results([group]), ["srnn"], "cmd", None, "abc1234", TARGETS)
    provenance = next(b for b in page.split("\n\n") if "| run folder " in b.split("\n")[0])
    assert [r[1] for r in cells(provenance)] == ["2", "1234"]
    (line,) = [x for x in page.splitlines() if x.startswith("**Runs counted once.**")]
    assert single["path"] in line and sweep["path"] in line
    # Of a resumed run and its earlier segment, the one that trained longer is kept.
    short = copy.deepcopy(single)
    short.update(path="killed", iterations=1000, finished=False)
    short["validations"] = {500: {80: 0.5}, 1000: {80: 0.45}}
    single["validations"] = {1500: {80: 0.4}}
    (group,) = group_runs([single, short])
    assert group.runs == [single] and "`killed` (1,000)" in group.left_out[0]
    assert list(single["validations"]) == [1500]  # its own curve: a resume continues in place


def test_the_page_goes_to_the_commands_folder_unless_out_is_given(tmp_path, monkeypatch):
    from src.config import PROJECT_ROOT

    shipped = PROJECT_ROOT / "docs" / "results.md"
    before = shipped.read_bytes()
    monkeypatch.setattr("src.reporting.runs.checkpoint_facts", lambda path: (4000, []))

    def evaluate_run(run, index, protocols, work):
        result = offset_result(0.0)
        run["rows"] = rows_of({s: {p: result for p in protocols} for s in ("best", "last")})

    monkeypatch.setattr("src.report.evaluate_run", evaluate_run)
    run = make_run(tmp_path / "runs" / "li2018_h36m" / "t", summary={"iterations": 4000})
    args = [f"runs=[{run}]", "protocols=[srnn]", "datasets=[]", "budget=b"]
    assert main(report_cfg(tmp_path, *args)) == 0
    assert shipped.read_bytes() == before
    page = (tmp_path / "work" / "results.md").read_text()
    assert (tmp_path / "work" / "results_errors.png").is_file()
    assert (tmp_path / "work" / "results" / "euler_srnn.csv").is_file()
    # Run folders are named relative to their common folder, not as absolute paths.
    assert "`li2018_h36m/t`" in page and str(tmp_path) not in page.split("## Command")[0]
    # out= names the file; the figures and the CSVs go beside it.
    out = tmp_path / "site" / "page.md"
    assert main(report_cfg(tmp_path, *args, f"out={out}", work="w2")) == 0
    assert out.is_file() and (tmp_path / "site" / "page_errors.png").is_file()
    assert (tmp_path / "site" / "page" / "mpjpe_srnn.csv").is_file()


def test_run_folders_are_shown_relative_to_their_common_folder(tmp_path):
    a = tmp_path / "out" / "job1" / "train" / "runs" / "li2018_h36m" / "t1"
    b = tmp_path / "out" / "job2" / "train" / "runs" / "li2018_cmu" / "t2"
    for run in (a, b):
        run.mkdir(parents=True)
    assert display_root([a, b]) == tmp_path / "out"
    assert display_root([a]) == a.parent.parent  # one run: li2018_h36m/t1, not "."
    # The segments of one resumed run: li2018_h36m/t1 and li2018_h36m/t3, not t1 and t3.
    c = a.parent / "t3"
    c.mkdir()
    assert display_root([a, c]) == a.parent.parent


# --- Li et al.'s ablation claims --------------------------------------------------------------


def ablation(name: str, delta: float) -> dict:
    run = seeded(delta, 1, name)
    return run


def claims_page(runs) -> str:
    return "\n".join(claims_section(Results(group_runs(runs)), ["srnn", "random"], "Ablations"))


def claim_rows(text: str) -> list[list[str]]:
    """Every table row of the section, as stripped cells."""
    return [
        [c.strip() for c in line.strip("|").split("|")]
        for line in text.splitlines()
        if line.startswith("|") and not line.startswith("|:")
    ]


def pair_rows(text: str, start: str) -> list[list[str]]:
    """The rows of the pair whose first cell starts with `start`, with their continuation."""
    rows, found = [], False
    for row in claim_rows(text):
        if row[0].startswith(start):
            found = True
        elif row[0]:
            found = False
        if found:
            rows.append(row)
    return rows


def test_an_ablation_is_compared_with_the_full_models_runs_of_its_own_budget():
    """Issue 39: li2018_h36m at 20,000 iterations joins its 4,000-iteration seeds; the ablations
    (4,000) are still compared with the 4,000, not with a longer-trained base."""
    short = [seeded(d, s) for s, d in ((1, 0.0), (2, 0.01), (3, -0.01))]
    long = [seeded(-0.10, s) for s in (1, 2, 3)]
    for run in long:
        run["config"].update(iterations=20000, val_every=2000)
        run["config"]["data"]["steps_per_epoch"] = 2000
        run["iterations"] = 20000
    text = claims_page(long + short + [ablation("li2018_h36m_no_long_term", 0.05)])
    first = pair_rows(text, "no_long_term − li2018_h36m (")[0]
    assert first[:4] == [
        "no_long_term − li2018_h36m (1 seed and 3 seeds)",
        "8 windows",
        "best",
        "+0.05",
    ]


def test_each_claim_is_stated_with_the_papers_numbers_and_judged_against_the_seed_spread():
    # li2018_h36m: seeds at -0.01, 0, +0.01 (spread 0.02); the ablations one seed each.
    full = [seeded(d, s) for s, d in ((1, 0.0), (2, 0.01), (3, -0.01))]
    effects = {
        "li2018_h36m_no_long_term": 0.05,  # higher by more than the spread: agrees
        "li2018_h36m_kernel_4x4": 0.01,  # within the spread: cannot tell
        "li2018_h36m_kernel_7x2": -0.05,  # lower by more than the spread: disagrees
    }
    text = claims_page(full + [ablation(n, d) for n, d in effects.items()])
    assert "0.41 0.72 1.05 1.17 1.88 against 0.38 0.68 1.01 1.13 1.77" in text  # Table 5
    paper = next(r for r in claim_rows(text) if r[0] == "no_long_term − li2018_h36m, paper")
    assert paper[1:5] == ["-", "-", "+0.03", "+0.04"]
    rows = {
        name: pair_rows(text, f"{name} − li2018_h36m (")
        for name in ("no_long_term", "kernel_4x4", "kernel_7x2")
    }
    first = rows["no_long_term"][0]
    assert first[:4] == [
        "no_long_term − li2018_h36m (1 seed and 3 seeds)",
        "8 windows",
        "best",
        "+0.05",
    ]
    assert first[-1] == "agrees, beyond the seed spread"
    assert "(+0.01)" in rows["kernel_4x4"][0] and rows["kernel_4x4"][0][-1].endswith(
        "(within the spread)"
    )
    assert rows["kernel_7x2"][0][-1] == (
        "disagrees: opposite beyond the spread at 80, 160, 320, 400, 1000 ms"
    )
    # Both protocols, both checkpoints: 4 rows a pair.
    assert [r[1:3] for r in rows["kernel_7x2"]] == [
        ["8 windows", "best"],
        ["8 windows", "last"],
        ["256 windows", "best"],
        ["256 windows", "last"],
    ]
    spread = next(r for r in claim_rows(text) if r[0] == "seed spread of li2018_h36m")
    assert spread[1:4] == ["8 windows", "best", "0.02"]
    # Only the claims with a trained pair are shown: the Figure 4 ones are left out.
    assert "### The 2x7 kernel (Table 6)" in text and "Figure 4" not in text.split("##")[2]
    assert "not trained" not in text


def test_c20_is_li2018_h36m_under_another_name():
    full = [seeded(d, s) for s, d in ((1, 0.0), (2, 0.01), (3, -0.01))]
    c20 = copy.deepcopy(full[0])
    c20["config"]["run_name"] = "li2018_h36m_C20"
    no_adv = ablation("li2018_h36m_C20_no_adv", 0.05)
    text = claims_page([*full, c20, no_adv])
    assert "is li2018_h36m's configuration" in text and "mean over its 3 seeds" in text
    # C = 20 with the regulariser is li2018_h36m's mean over its 3 seeds.
    (row, *_) = pair_rows(text, "C20_no_adv − C20 (")
    assert row[:3] == ["C20_no_adv − C20 (1 seed and 3 seeds)", "8 windows", "best"]
    # A C20 run with another budget stands on its own.
    c20["config"]["iterations"] = 2000
    text = claims_page([*full, c20, no_adv])
    assert "li2018_h36m_C20 differs from li2018_h36m in iterations 2000 vs 4000" in text
    assert pair_rows(text, "C20_no_adv − C20 (")[0][0] == "C20_no_adv − C20 (1 seed and 1 seed)"
    # The other pair of the claim was not trained, and the row says so.
    (untrained,) = pair_rows(text, "C10_no_adv − C10")
    assert untrained[-1] == "not trained: li2018_h36m_C10_no_adv, li2018_h36m_C10"


def test_one_seed_of_li2018_h36m_cannot_judge_a_difference():
    text = claims_page([seeded(0.0, 1), ablation("li2018_h36m_no_long_term", 0.05)])
    assert "same direction at 5 of 5 (no seed spread to judge by)" in text
    assert "(+0.05)" not in text


@pytest.mark.parametrize("delta", [0.003, -0.003])
def test_a_difference_printed_as_zero_is_not_counted_as_a_direction(delta):
    # Seen with real runs: +0.00 at every horizon, yet "same direction at 3 of 5".
    text = claims_page([seeded(0.0, 1), ablation("li2018_h36m_no_long_term", delta)])
    row = pair_rows(text, "no_long_term − li2018_h36m (")[0]
    assert row[1:5] == ["8 windows", "best", "+0.00", "+0.00"]
    assert row[-1] == (
        "same direction at 0 of 5, 0.00 at 80, 160, 320, 400, 1000 ms (no seed spread to judge by)"
    )


def test_no_ablation_section_before_an_ablation_is_trained():
    """A page of li2018_h36m alone used to print every claim with empty rows."""
    assert claims_page([seeded(d, s) for s, d in ((1, 0.0), (2, 0.01))]) == ""
    # Without li2018_h36m there is nothing to compare with either (a CMU-only page).
    assert claims_page([seeded(0.0, 1, "li2018_cmu", "cmu", absent=[])]) == ""
    # C = 5 alone has no pair to be compared in: still no section.
    assert claims_page([seeded(0.0, 1), ablation("li2018_h36m_C5", 0.01)]) == ""
    text = claims_page(
        [seeded(0.0, 1), *(ablation(f"li2018_h36m_{c}", 0.01) for c in ("C5", "C10"))]
    )
    assert [line for line in text.splitlines() if line.startswith("### ")] == [
        "### Short-term window C = 5 against 10 (Figure 4, middle)",
        "### Short-term window C = 10 against 20 (Figure 4, middle)",
    ]
    (untrained,) = pair_rows(text, "C5_no_adv − C10_no_adv")
    assert untrained[-1] == "not trained: li2018_h36m_C5_no_adv, li2018_h36m_C10_no_adv"
    assert {c.title for c in claims()} >= {"The long-term encoder (Table 5)"}


@pytest.mark.parametrize("delta, verdict", [(0.05, "disagrees"), (0.0, "agrees")])
def test_no_gain_from_c10_to_c20(delta, verdict):
    full = [seeded(d, s) for s, d in ((1, 0.0), (2, 0.01), (3, -0.01))]
    text = claims_page([*full, ablation("li2018_h36m_C10", delta)])
    row = pair_rows(text, "C10 − C20 (")[0]
    assert row[1:3] == ["8 windows", "best"] and row[-1].startswith(verdict)
