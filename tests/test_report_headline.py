"""The results page's headline (one table of every trained experiment against its published
references, first on the page and in the README), the GRU judged against both published
sources, the slips of the papers, identical runs counted once, where the page is written, and
Li et al.'s ablation claims. Built from stored evaluation results, in seconds; the slow
end-to-end check is tests/test_report.py::test_report_from_a_short_run."""

import copy
import re

import pytest

from src.report import main, new_folder
from src.reporting.claims import ABLATIONS, claims, claims_section
from src.reporting.groups import group_runs
from src.reporting.headline import headline_figure, headline_table, page_order, readme_block
from src.reporting.page import build_page, how_to_read, summary_table
from src.reporting.published import KNOWN_SLIPS, published_for
from src.reporting.runs import display_root
from src.reporting.tables import AVERAGE, ResultTable, same_set_average
from src.reporting.verdicts import gap_lines, judge, references, slip_lines
from tests.test_report import ABSENT, MS, fake_run, make_run, offset_result, offset_run

EVALUATED = [
    "walking", "eating", "smoking", "greeting", "phoning", "posing", "purchases", "sitting",
    "takingphoto", "walkingdog", "walkingtogether",
]  # fmt: skip
GRU = {"h36m": {"paper": "martinez2017", "method": "residual_sup_ma"}}


def gru_result(delta: float) -> dict:
    """A GRU evaluation as src.eval stores it (Martinez et al.'s values beside ours), where
    every evaluated action is Li et al.'s RRNN value + delta (1.0 where RRNN has none)."""
    published, label = published_for(GRU, "h36m")
    rrnn, _ = published_for({"paper": "li2018", "method": "rrnn"}, "h36m")
    actions = [a for a in published if a != AVERAGE]
    values = {a: {ms: rrnn[a].get(ms, 1.0 - delta) + delta for ms in MS} for a in EVALUATED}
    tables = [
        ResultTable(
            "t", m, u, actions, MS, values, ABSENT, published if m == "euler" else None, label
        ).to_dict()
        for m, u in (("euler", "rad"), ("mpjpe", "mm"))
    ]
    return {"provenance": {"missing_files": []}, "tables": tables}


def gru_run(seed: int, delta: float) -> dict:
    run = fake_run(seed, 0.0, 0.0, "martinez2017_res_sup")
    result = gru_result(delta)
    run["results"] = {s: {"srnn": result, "random": result} for s in ("best", "last")}
    return run


def seeded(delta: float, seed: int, run_name="li2018_h36m", dataset="h36m", absent=ABSENT):
    run = offset_run(delta, run_name, dataset, absent=absent)
    run["seed"] = run["config"]["seed"] = seed
    run["path"] = f"job{seed}/train/runs/{run_name}/2026-01-01_00-00-00"
    results = {p: offset_result(delta, dataset, absent) for p in ("srnn", "random")}
    run["results"] = {"best": results, "last": results}
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


def test_the_gru_has_both_published_sources_each_with_its_same_set_gap():
    (group,) = group_runs([gru_run(1, 0.0)])
    refs = references(group)
    assert [r.key for r in refs] == ["martinez2017 residual_sup_ma", "li2018 rrnn"]
    rrnn_same = same_set_average(refs[1].published, EVALUATED, MS)
    martinez_same = same_set_average(refs[0].published, EVALUATED, MS)
    # The numbers: RRNN over these 11 actions .430 .741 1.119 1.260 1.820.
    assert [round(rrnn_same[ms], 3) for ms in (80, 160, 320, 400, 1000)] == [
        0.43, 0.741, 1.119, 1.26, 1.82,
    ]  # fmt: skip
    lines = gap_lines(group, "best", "srnn", 0.03)
    (martinez,) = [line for line in lines if "(martinez2017 residual_sup_ma)" in line]
    (rrnn,) = [line for line in lines if "(li2018 rrnn)" in line]
    assert (
        f"80 ms {0.43 - round(martinez_same[80], 2):+.2f}" in martinez and "NOT within" in martinez
    )
    assert "80 ms +0.00" in rrnn and "1000 ms +0.00" in rrnn and "within the target" in rrnn
    assert "NOT" not in rrnn
    # Both in the averages table too, each flagged for its own slips.
    table = summary_table([group], [], "euler", "srnn")
    assert "published (martinez2017 residual_sup_ma), same 11 actions (includes slips" in table
    assert "published (li2018 rrnn), same 11 actions |" in table


def test_the_verdict_names_the_reference_it_was_judged_against_and_why():
    groups = group_runs([gru_run(s, d) for s, d in ((1, 0.0), (2, 0.004), (3, -0.003))])
    verdict = judge(groups[0], "srnn", 0.03)
    assert (verdict.status, verdict.reference.key) == ("reproduces", "li2018 rrnn")
    assert "martinez2017 residual_sup_ma" not in verdict.why
    assert "Martinez et al. residual_sup_ma's same-set average includes slips" in verdict.why
    assert "(smoking, phoning)" in verdict.why
    block = readme_block(groups, "srnn", "abc1234")
    (best,) = [line for line in block.splitlines() if "| ours, best |" in line]
    assert best.endswith("| **reproduces**, judged against Li et al. rrnn¹ |")
    (footnote,) = [line for line in block.splitlines() if line.startswith("- ¹")]
    assert "retraining of the same model" in footnote and "smoking, phoning" in footnote
    # Against Martinez et al.'s printed rows it misses, and the row says where.
    (martinez,) = [line for line in block.splitlines() if "|  |  | Martinez et al." in line]
    assert martinez.endswith("| beyond 0.03 at 80, 160, 320, 400 ms |")
    # A model with one reference is judged against it, with no reason needed.
    (li,) = group_runs([seeded(0.0, 1)])
    assert judge(li, "srnn", 0.03).why == "the only published source"


def test_without_a_slip_the_models_own_paper_is_the_judge():
    """Where the data copy lacks the actions that carry the slips, the GRU is judged against
    Martinez et al., its own paper."""
    run = gru_run(1, 0.0)
    for result in {id(r): r for s in run["results"].values() for r in s.values()}.values():
        for table in result["tables"]:
            for action in ("smoking", "phoning"):
                table["values"].pop(action)
                table["absent"][action] = "not in this copy"
    (group,) = group_runs([run])
    verdict = judge(group, "srnn", 0.03)
    assert verdict.reference.key == "martinez2017 residual_sup_ma"
    assert verdict.why == "the model's own paper" and verdict.status == "misses"


# --- the slip flag ---------------------------------------------------------------------------


def test_martinez_phoning_is_a_known_slip_flagged_where_it_enters_an_average():
    why = KNOWN_SLIPS[("martinez2017", "residual_sup_ma")]["phoning"]
    # The evidence is the CSV's: Martinez's row against Li's retraining and Li's own model.
    for paper, method, row in (
        ("martinez2017", "residual_sup_ma", "0.23 0.43 0.69 0.82"),
        ("li2018", "rrnn", "0.62 1.10 1.54 1.70"),
        ("li2018", "conv_s2s", "0.59 1.13 1.51 1.65"),
    ):
        published, _ = published_for({"paper": paper, "method": method}, "h36m")
        assert " ".join(f"{published['phoning'][ms]:.2f}" for ms in (80, 160, 320, 400)) == row
        assert row in why
    (group,) = group_runs([gru_run(1, 0.0)])
    (line,) = slip_lines(group, "srnn")
    assert "(martinez2017 residual_sup_ma) of smoking, phoning" in line
    block = readme_block([group], "srnn", "abc1234")
    assert "Martinez et al. residual_sup_ma, 11 actions incl. slips (smoking, phoning) |" in block
    assert "Li et al. rrnn, 11 actions |" in block  # RRNN's average has no slip
    # Without phoning among the evaluated actions, the flag names smoking only.
    assert "incl. slips (smoking) |" in headline_without(group, "phoning")


def headline_without(group, action: str) -> str:
    group = copy.deepcopy(group)
    for run in group.runs:
        for result in {id(r): r for s in run["results"].values() for r in s.values()}.values():
            for table in result["tables"]:
                table["values"].pop(action)
                table["absent"][action] = "not in this copy"
    return readme_block([group], "srnn", "abc1234")


# --- the headline -----------------------------------------------------------------------------


def paragraphs(text: str) -> list[str]:
    """Prose paragraphs of markdown: blocks between blank lines, each list item on its own,
    tables aside."""
    blocks = [b for b in text.split("\n\n") if b.strip() and not b.lstrip().startswith("|")]
    return [item for b in blocks for item in re.split(r"\n(?=- )", b)]


def test_headline_first_and_readme_block_short_on_the_leads_runs(tmp_path):
    groups = group_runs(lead_like_runs())
    figure = headline_figure(groups, "srnn")
    page = build_page(
        groups, [], ["srnn", "random"], "python -m src.report ...", "b" * 2000, "abc1234",
        figure="results_errors.png",
    )  # fmt: skip
    lines = page.splitlines()
    first_table = next(
        k for k, line in enumerate(lines) if line.startswith("| ") and " ms |" in line
    )
    assert first_table < 30
    header = lines[first_table]
    assert header.startswith("| experiment | data | row | n | 80 ms |") and "| verdict |" in header
    # One short label per experiment, the ablations in their own section.
    labels = [
        line.split(" | ")[0][2:] for line in lines[first_table + 2 :] if "| ours, best" in line
    ]
    assert labels[:3] == ["li2018_h36m", "li2018_cmu", "martinez2017_res_sup"]
    assert len(labels) == 3
    assert "![Average Euler error against horizon, ours and published](results_errors.png)" in page
    # Then, in that order: provenance, per-action tables, the 256 windows, MPJPE, the command.
    order = [
        "**Budget.**",
        "## Ablations",
        "## Provenance",
        "## Per-action tables: 8 windows",
        "## Other protocol: 256 windows",
        "## MPJPE",
        "## Command",
    ]
    assert [page.index(h) for h in order] == sorted(page.index(h) for h in order)
    assert page.rstrip().endswith("`python -m src.report ...`")

    block = readme_block(groups, "srnn", "abc1234", None, "docs/results_errors.png")
    assert len(block.splitlines()) <= 25
    assert all(len(p) <= 300 for p in paragraphs(block)), [len(p) for p in paragraphs(block)]
    assert "![Average Euler error against horizon" in block and "b" * 50 not in block
    assert "[docs/results.md](docs/results.md)" in block and "docs/results.md#ablations" in block
    # The figure: one panel per dataset.
    assert [ax.get_title().split(":")[0] for ax in figure.axes] == ["h36m", "cmu"]
    figure.savefig(tmp_path / "f.png")
    assert (tmp_path / "f.png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.parametrize("n, rows", [(1, "1 trained row:"), (2, "2 trained rows:")])
def test_the_headline_counts_the_trained_ablations(n, rows):
    groups = group_runs([seeded(0.0, 1)] + [seeded(0.0, 1, name) for name in ABLATIONS[:n]])
    table, notes = headline_table(groups, "srnn", {"h36m": 0.03}, "#ablations")
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
    groups = page_order(group_runs(found))
    order = ["li2018_h36m", "martinez2017_res_sup", "li2018_cmu", ABLATIONS[0]]
    assert [g.label for g in groups] == order
    (seeds,) = [line for line in how_to_read(groups) if line.startswith("**Seeds.**")]
    assert seeds.startswith("**Seeds.** li2018_h36m (h36m): 2 seeds (1, 2); martinez2017_res_sup")
    rows = [r for r in readme_block(groups, "srnn", "abc").splitlines() if "| ours, best |" in r]
    assert [r.split(" | ")[0].strip("| ") for r in rows] == order[:3]


def test_settings_that_tell_rows_apart_go_to_a_footnote():
    switched = seeded(0.0, 1)
    switched["config"]["adversarial"]["reference_fake_slot"] = True
    groups = group_runs([seeded(0.0, 1), switched])
    block = readme_block(groups, "srnn", "abc1234")
    rows = [line for line in block.splitlines() if "| ours, best |" in line]
    assert rows[0].startswith("| li2018_h36m¹ | h36m |")
    assert rows[1].startswith("| li2018_h36m, reference-code switches² | h36m |")
    assert "- ¹ li2018_h36m: adversarial.reference_fake_slot=False." in block
    assert (
        "- ² li2018_h36m, reference-code switches: adversarial.reference_fake_slot=True." in block
    )


# --- identical runs are one seed --------------------------------------------------------------


def test_a_run_and_a_sweep_job_with_the_same_config_and_seed_are_one_seed():
    single = seeded(0.0, 1234)
    sweep = copy.deepcopy(single)
    sweep["path"] = "multiruns/2026-01-01/0_li2018_h36m_seed1234"
    (group,) = group_runs([single, sweep, seeded(0.01, 2)])
    assert [r["seed"] for r in group.runs] == [2, 1234]  # in seed order
    assert group.runs[1] is single
    (line,) = group.left_out
    assert "seed 1234: `multiruns/2026-01-01/0_li2018_h36m_seed1234` has the same" in line
    assert f"`{single['path']}`, which was kept (given first)" in line
    page = build_page([group], [], ["srnn"], "cmd", None, "abc1234")
    assert "li2018_h36m (h36m): 2 seeds (2, 1234)" in page and "(1234, 1234)" not in page
    assert "**Runs counted once.** seed 1234:" in page
    # Of a run and its unfinished earlier copy, the one that trained longer is kept.
    short = copy.deepcopy(single)
    short.update(path="killed", iterations=1000, finished=False)
    (group,) = group_runs([short, single])
    assert (
        group.runs == [single]
        and "(it trained 4,000 iterations, that one 1,000)" in (group.left_out[0])
    )


def test_the_segments_of_a_resumed_run_are_named_as_such_and_a_copy_as_a_copy():
    def segment(folder, iterations, resumed_from=None):
        run = seeded(0.0, 3)
        run.update(path=folder.strip("/"), folder=folder, iterations=iterations)
        if resumed_from:
            run["config"]["ckpt_path"] = f"{resumed_from}/checkpoints/last.ckpt"
        return run

    first = segment("/o/s3/t1", 533)
    second = segment("/o/s3/t2", 2839, "/o/s3/t1")
    last = segment("/o/s3/t3", 4000, "/o/s3/t2")
    copy_ = segment("/o/copy/t1", 1000)  # the same settings and seed, trained apart
    for order in ([first, second, last, copy_], [copy_, last, second, first]):
        (group,) = group_runs(order)
        assert group.runs == [last]
        lines = sorted(group.left_out)
        assert lines[0] == (
            "seed 3: `o/copy/t1` has the same configuration and seed as `o/s3/t3`, which was "
            "kept (it trained 4,000 iterations, that one 1,000); they count as one seed"
        )
        assert lines[1:] == [
            f"seed 3: `o/s3/{t}` ({n} iterations) is an earlier segment of the resumed run "
            "`o/s3/t3` (4,000), which was kept"
            for t, n in (("t1", "533"), ("t2", "2,839"))
        ]
    # A copy that was itself resumed from another folder is still a copy.
    copy_["config"]["ckpt_path"] = "/o/elsewhere/checkpoints/last.ckpt"
    (group,) = group_runs([last, second, first, copy_])
    assert sum("same configuration" in line for line in group.left_out) == 1


# --- where the page goes ----------------------------------------------------------------------


def test_the_page_goes_to_the_commands_folder_unless_out_is_given(tmp_path, monkeypatch):
    from src.lit.factory import PROJECT_ROOT

    shipped = PROJECT_ROOT / "docs" / "results.md"
    before = shipped.read_bytes()
    monkeypatch.setattr("src.reporting.runs.checkpoint_facts", lambda path: (4000, []))

    def evaluate_run(run, index, protocols, work):
        result = offset_result(0.0)
        run["results"] = {s: {p: result for p in protocols} for s in ("best", "last")}

    monkeypatch.setattr("src.report.evaluate_run", evaluate_run)
    run = make_run(tmp_path / "runs" / "li2018_h36m" / "t", summary={"iterations": 4000})
    args = [str(run), "--protocols", "srnn", "--datasets", "none", "--budget", "b"]
    assert main([*args, "--work-dir", str(tmp_path / "work")]) == 0
    assert shipped.read_bytes() == before
    page = (tmp_path / "work" / "results.md").read_text()
    assert (tmp_path / "work" / "results_errors.png").is_file()
    # Run folders are named relative to their common folder, not as absolute paths.
    assert "`li2018_h36m/t`" in page and str(tmp_path) not in page.split("## Command")[0]
    # --out names the file; the figure goes beside it.
    out = tmp_path / "site" / "page.md"
    assert main([*args, "--work-dir", str(tmp_path / "w2"), "--out", str(out)]) == 0
    assert out.is_file() and (tmp_path / "site" / "page_errors.png").is_file()
    # Without --work-dir, each report gets a new folder of its own.
    base = tmp_path / "report" / "2026-01-01_00-00-00"
    assert [new_folder(base).name for _ in range(3)] == [
        "2026-01-01_00-00-00",
        "2026-01-01_00-00-00-1",
        "2026-01-01_00-00-00-2",
    ]


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
    return "\n".join(claims_section(group_runs(runs), ["srnn", "random"], "Ablations"))


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
    assert "| no_long_term − li2018_h36m, paper | - | - | +0.03 | +0.04 |" in text
    rows = {
        name: [line for line in text.splitlines() if re.match(rf"\| {name} − li2018_h36m \(", line)]
        for name in ("no_long_term", "kernel_4x4", "kernel_7x2")
    }
    assert rows["no_long_term"][0].startswith(
        "| no_long_term − li2018_h36m (1 seed and 3 seeds) | 8 windows | best | +0.05 |"
    )
    assert rows["no_long_term"][0].endswith("| agrees, beyond the seed spread |")
    assert "| (+0.01) |" in rows["kernel_4x4"][0]
    assert rows["kernel_4x4"][0].endswith("(within the spread) |")
    assert (
        "disagrees: opposite beyond the spread at 80, 160, 320, 400, 1000 ms"
        in (rows["kernel_7x2"][0])
    )
    # Both protocols, both checkpoints: 4 rows a pair.
    assert "| 256 windows | last |" in text
    assert "| seed spread of li2018_h36m | 8 windows | best | 0.02 |" in text
    # Claims whose runs were not trained say so.
    assert "not trained: li2018_h36m_C5" in text


def test_c20_is_li2018_h36m_under_another_name():
    full = [seeded(d, s) for s, d in ((1, 0.0), (2, 0.01), (3, -0.01))]
    c20 = copy.deepcopy(full[0])
    c20["config"]["run_name"] = "li2018_h36m_C20"
    no_adv = ablation("li2018_h36m_C20_no_adv", 0.05)
    text = claims_page([*full, c20, no_adv])
    assert "li2018_h36m_C20 has li2018_h36m's configuration" in text
    assert "averages differ by at most 0.0e+00 rad (identical)" in text
    # C = 20 with the regulariser is li2018_h36m's mean over its 3 seeds.
    assert "| C20_no_adv − C20 (1 seed and 3 seeds) | 8 windows | best |" in text
    # A C20 run with another budget stands on its own.
    c20["config"]["iterations"] = 2000
    text = claims_page([*full, c20, no_adv])
    assert "li2018_h36m_C20 differs from li2018_h36m in iterations 2000 vs 4000" in text
    assert "| C20_no_adv − C20 (1 seed and 1 seed) |" in text


def test_one_seed_of_li2018_h36m_cannot_judge_a_difference():
    text = claims_page([seeded(0.0, 1), ablation("li2018_h36m_no_long_term", 0.05)])
    assert "same direction at 5 of 5 (no seed spread to judge by)" in text
    assert "(+0.05)" not in text


@pytest.mark.parametrize("delta", [0.003, -0.003])
def test_a_difference_printed_as_zero_is_not_counted_as_a_direction(delta):
    # Seen with real runs: +0.00 at every horizon, yet "same direction at 3 of 5".
    text = claims_page([seeded(0.0, 1), ablation("li2018_h36m_no_long_term", delta)])
    start = "| no_long_term − li2018_h36m ("
    row = next(line for line in text.splitlines() if line.startswith(start))
    assert "| 8 windows | best | +0.00 | +0.00 |" in row
    assert row.endswith(
        "| same direction at 0 of 5, 0.00 at 80, 160, 320, 400, 1000 ms "
        "(no seed spread to judge by) |"
    )


def test_before_any_ablation_is_trained_the_claims_are_listed_as_unchecked():
    full = [seeded(d, s) for s, d in ((1, 0.0), (2, 0.01))]
    text = claims_page(full)
    assert text.startswith("## Ablations")
    for claim in claims():
        assert f"### {claim.title}" in text
    assert "| no_long_term − li2018_h36m, paper | - | - | +0.03 | +0.04 |" in text  # Table 5
    assert "not trained: li2018_h36m_no_long_term |" in text
    assert "not trained: li2018_h36m_C20_no_adv |" in text
    # Without li2018_h36m there is nothing to compare with: no section (a CMU-only page).
    assert claims_page([seeded(0.0, 1, "li2018_cmu", "cmu", absent=[])]) == ""


@pytest.mark.parametrize("delta, verdict", [(0.05, "disagrees"), (0.0, "agrees")])
def test_no_gain_from_c10_to_c20(delta, verdict):
    full = [seeded(d, s) for s, d in ((1, 0.0), (2, 0.01), (3, -0.01))]
    text = claims_page([*full, ablation("li2018_h36m_C10", delta)])
    (row,) = [
        line
        for line in text.splitlines()
        if line.startswith("| C10 − C20 (") and "| 8 windows | best |" in line
    ]
    assert row.split(" | ")[-1].startswith(verdict)
