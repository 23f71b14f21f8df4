"""Run records (`src.report records=DIR`): a page rebuilt from the records of its runs, without
their folders, is the page built from the runs; a new run joins the recorded ones and is the
only one evaluated; the same run given again counts once and replaces its record; records name
no machine's paths; a bad record is refused naming the file and the fix. The evaluations are
stored results (tests/test_report.py), so these take seconds."""

import json
import re

import pytest

from src.report import main
from tests.test_report import (
    cells,
    headline_in,
    make_run,
    offset_result,
    refusal,
    report_cfg,
    rows_of,
)


@pytest.fixture
def evaluations(monkeypatch):
    """src.report with stored evaluations: run i of seed s evaluates to the published value +
    s / 100, its results naming the checkpoint by an absolute path as src.eval does. Returns
    the list of run folders evaluated, in order."""
    evaluated = []
    monkeypatch.setattr("src.reporting.runs.checkpoint_facts", lambda path: (4000, []))

    def evaluate_run(run, index, protocols, work):
        evaluated.append(run["path"])
        result = offset_result(run["seed"] / 100)
        rows = rows_of({s: {p: result for p in protocols} for s in ("best", "last")})
        keys = {"experiment": run["config"]["run_name"], "dataset": run["config"]["data"]["name"]}
        run["rows"] = rows.assign(run=run["path"], seed=run["seed"], iterations=4000, **keys)

    monkeypatch.setattr("src.report.evaluate_run", evaluate_run)
    return evaluated


@pytest.fixture
def records(tmp_path):
    """An empty folder of records."""
    folder = tmp_path / "records"
    folder.mkdir()
    return folder


def report(tmp_path, *runs, records=None) -> str:
    """Run src.report on `runs` with the test's fixed options; returns the page."""
    k = len(list(tmp_path.glob("page*")))
    out = tmp_path / f"page{k}" / "results.md"
    args = [
        f"runs=[{','.join(map(str, runs))}]",
        "protocols=[srnn]",
        "datasets=[]",
        "budget=b",
        f"out={out}",
    ] + ([f"records={records}"] if records else [])
    assert main(report_cfg(tmp_path, *args, work=f"work{k}")) == 0
    return out.read_text()


def without_record_notes(page: str) -> str:
    """The page less its command line and the provenance notes that name records, its tables
    without their padding."""
    body = page.split("## Command")[0]
    lines = [
        "|".join(c.strip() for c in line.split("|")) if line.startswith("|") else line
        for line in body.splitlines()
        if not line.startswith("|:")
    ]
    note = r"record [^\s|]+: evaluated at [^\s|]+ on [^\s|]+"
    return re.sub(rf"\|{note}\|", "|-|", re.sub(f"; {note}", "", "\n".join(lines)))


def seeds(page: str) -> list[tuple[str, str]]:
    """(experiment, seed) of each provenance row."""
    table = page.split("## Provenance")[1].split("\n\n")[1]
    return [(r[0], r[1]) for r in cells(table)]


def seed_run(tmp_path, seed: int, run_name="li2018_h36m"):
    folder = tmp_path / "runs" / f"{run_name}_s{seed}" / "t"
    return make_run(folder, summary={"iterations": 4000}, seed=seed, run_name=run_name)


def test_a_page_from_the_records_alone_is_the_page_from_the_runs(tmp_path, evaluations, records):
    runs = [seed_run(tmp_path, 1), seed_run(tmp_path, 2)]
    from_runs = report(tmp_path, *runs, records=records)
    assert len(evaluations) == 2 and len(list(records.glob("*.json"))) == 2
    from_records = report(tmp_path, records=records)
    assert len(evaluations) == 2  # nothing evaluated again
    assert without_record_notes(from_records) == without_record_notes(from_runs)
    assert seeds(from_records) == [("li2018_h36m", "1"), ("li2018_h36m", "2")]
    # The page says which rows came from a record, and when they were evaluated.
    assert from_records.count("record li2018_h36m_h36m_") == 2
    assert "record li2018_h36m_" not in from_runs


def test_a_new_seed_joins_the_recorded_ones_and_only_it_is_evaluated(
    tmp_path, evaluations, records
):
    report(tmp_path, seed_run(tmp_path, 1), records=records)
    (first,) = records.glob("*.json")
    before = first.read_bytes()
    page = report(tmp_path, seed_run(tmp_path, 2), records=records)
    assert evaluations == ["li2018_h36m_s1/t", "li2018_h36m_s2/t"]
    assert first.read_bytes() == before and len(list(records.glob("*.json"))) == 2
    # Both seeds are on the page: seed 1 from its record, seed 2 from its folder.
    assert seeds(page) == [("li2018_h36m", "1"), ("li2018_h36m", "2")]


def test_the_same_run_given_again_counts_once_and_replaces_its_record(
    tmp_path, evaluations, records
):
    run = seed_run(tmp_path, 1)
    report(tmp_path, run, records=records)
    page = report(tmp_path, run, records=records)
    assert len(evaluations) == 2  # the folder given wins over its record, and is evaluated
    assert len(list(records.glob("*.json"))) == 1
    assert seeds(page) == [("li2018_h36m", "1")]
    assert "Runs counted once" not in page  # not a copy of itself
    # Given beside a run from elsewhere, it shows under a longer path: still its own record.
    other = seed_run(tmp_path / "elsewhere", 2)
    page = report(tmp_path, run, other, records=records)
    assert "`runs/li2018_h36m_s1/t`" in page and "Runs counted once" not in page
    assert seeds(page).count(("li2018_h36m", "1")) == 1 and len(list(records.glob("*.json"))) == 2
    # Another experiment of the same seed is another record, not a replacement.
    report(tmp_path, seed_run(tmp_path, 1, "li2018_h36m_C10"), records=records)
    assert len(list(records.glob("*.json"))) == 3


def test_records_name_no_machines_paths_and_hold_no_checkpoint(tmp_path, evaluations, records):
    report(tmp_path, seed_run(tmp_path, 1), records=records)
    (record,) = records.glob("*.json")
    text = record.read_text()
    assert str(tmp_path) not in text
    data = json.loads(text)
    assert data["checkpoints"]["best"] == "li2018_h36m_s1/t/checkpoints/last.ckpt"
    assert data["evaluated"]["commit"] and data["seed"] == 1


def test_a_resumed_runs_best_checkpoint_is_recorded_in_its_own_segments_folder(
    tmp_path, evaluations, records
):
    runs = tmp_path / "out" / "li2018_h36m_s1" / "train" / "runs" / "li2018_h36m"
    first = make_run(runs / "t1", files=("best-epoch001.ckpt", "last.ckpt"))  # stopped
    best = first / "checkpoints" / "best-epoch001.ckpt"
    summary = {"iterations": 4000, "best_checkpoint": str(best)}
    make_run(runs / "t2", summary=summary, ckpt_path=str(first / "checkpoints" / "last.ckpt"))
    page = report(tmp_path, tmp_path / "out" / "li2018_h36m_s1", records=records)
    # The stopped segment counts once with the finished run that continues it.
    (line,) = [x for x in page.splitlines() if x.startswith("**Runs counted once.**")]
    assert "`li2018_h36m/t2` (4,000 iterations) kept; `li2018_h36m/t1` (4,000)" in line
    (record,) = records.glob("*.json")
    data = json.loads(record.read_text())
    assert data["path"] == "li2018_h36m/t2"
    assert data["checkpoints"]["best"] == "li2018_h36m/t1/checkpoints/best-epoch001.ckpt"
    # A segment outside the folders given (resumed under another paths.log_dir): named by its
    # file inside the run's folder, not by an absolute path.
    best = tmp_path / "elsewhere" / "checkpoints" / "best-epoch002.ckpt"
    best.parent.mkdir(parents=True)
    best.touch()
    moved = make_run(tmp_path / "b" / "li2018_h36m" / "t3", summary={"best_checkpoint": str(best)})
    report(tmp_path, moved, records=records)
    (record,) = records.glob("*.json")
    assert str(tmp_path) not in record.read_text()
    checkpoint = json.loads(record.read_text())["checkpoints"]["best"]
    assert checkpoint == "li2018_h36m/t3/checkpoints/best-epoch002.ckpt"


@pytest.mark.parametrize(
    "content, says",
    [
        ("{not json", "is not valid JSON"),
        ('{"a": 1}', "is not a run record (no format, path, config"),
        ("WRONG_FORMAT", "evaluate its run again"),
        ("NO_RANDOM", "has no best-checkpoint results for protocol random: give protocols=[srnn]"),
    ],
)
def test_a_bad_record_is_refused_naming_the_file_and_the_fix(
    tmp_path, evaluations, records, content, says, capsys
):
    report(tmp_path, seed_run(tmp_path, 1), records=records)
    (record,) = records.glob("*.json")
    protocols = "protocols=[srnn,random]" if content == "NO_RANDOM" else "protocols=[srnn]"
    if content == "WRONG_FORMAT":
        record.write_text(record.read_text().replace('"format": 2', '"format": 99'))
    elif content != "NO_RANDOM":
        record.write_text(content)
    text = refusal(capsys, report_cfg(tmp_path, f"records={records}", "datasets=[]", protocols))
    assert str(record) in text and says in text and text.count("\n") == 1


def test_a_records_folder_that_does_not_exist_is_refused(tmp_path, evaluations, capsys):
    text = refusal(capsys, report_cfg(tmp_path, f"records={tmp_path / 'nope'}", "datasets=[]"))
    assert "is not a folder" in text


def test_the_page_puts_h36m_before_cmu_whatever_the_records_file_names(
    tmp_path, evaluations, records
):
    cmu = make_run(
        tmp_path / "runs" / "li2018_cmu_s1" / "t",
        summary={"iterations": 4000},
        run_name="li2018_cmu",
        data={"name": "cmu", "seed": 1},
    )
    report(tmp_path, cmu, seed_run(tmp_path, 1), records=records)
    assert sorted(p.name[:10] for p in records.glob("*.json")) == ["li2018_cmu", "li2018_h36"]
    page = report(tmp_path, records=records)
    rows = [r for r in cells(headline_in(page)) if r[3] == "ours, best"]
    assert [r[0] for r in rows] == ["li2018_h36m", "li2018_cmu"]
