"""Write the results page from finished training runs.

    python -m src.report outputs/train/runs/li2018_cmu/<time> --budget "4000 iterations on a GPU"
    python -m src.report outputs/reproduce/multiruns/<time> --out docs/results.md \
        --readme README.md --budget "..."

Arguments are run folders (config.yaml, summary.yaml, checkpoints/) or folders holding them,
such as a multirun of `python -m src.train -m reproduce=papers`. Runs are found in
src/reporting/runs.py and grouped by experiment and dataset in groups.py, seeds aggregated as
mean ± std; each run's best and last checkpoints and the baselines are evaluated on each
protocol (src/reporting/evaluation.py); the verdicts and the ablation claims are in
src/reporting/verdicts.py and claims.py, the page's layout in src/reporting/page.py and its
headline (also the README's block) in headline.py. Every number on the page comes from those
evaluations and the published tables; nothing is typed in.

The page and its figure go to the command's own folder (outputs/report/<time>/results.md)
unless --out names the file; --readme also puts the page's headline between the results
markers of that file.

With --records DIR, each run evaluated is also written to DIR as a small record (its
evaluations, no checkpoint), and the runs recorded there join the page without their folders
(src/reporting/records.py): a page can grow over several machines, a few runs at a time.

    python -m src.report <new runs> --records docs/runs --out docs/results.md --readme README.md
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import logging
import os
import shlex
import sys
from pathlib import Path

from src.lit.factory import PROJECT_ROOT, git_commit
from src.reporting.evaluation import evaluate_baselines, evaluate_run, mark_archives
from src.reporting.groups import group_runs, note_names, parse_notes
from src.reporting.headline import (
    check_block,
    headline_figure,
    page_order,
    readme_block,
    replace_block,
)
from src.reporting.page import build_page
from src.reporting.records import read_records, record_name, write_record
from src.reporting.runs import discover_runs, display_root, load_run, scored_entries
from src.reporting.verdicts import PROTOCOLS, TARGETS

__all__ = ["main", "replace_block"]


def new_folder(base: Path) -> Path:
    """Create and return `base`, or `base-1`, `base-2`... when taken (two reports in a second)."""
    candidate, n = base, 0
    while True:
        try:
            candidate.mkdir(parents=True)
            return candidate
        except FileExistsError:
            n += 1
            candidate = base.with_name(f"{base.name}-{n}")


def same_folder(a: str, b: str) -> bool:
    """Whether two shown paths name one run folder: each is relative to the root of the report
    that showed it (src/reporting/runs.py display_root), so the shorter ends the longer."""
    pa, pb = Path(a).parts, Path(b).parts
    n = min(len(pa), len(pb))
    return n > 0 and pa[-n:] == pb[-n:]


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "runs",
        nargs="*",
        type=Path,
        help="run folders, or folders holding them (a multirun folder)",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="the page to write, its figure beside it (default: results.md in the command's "
        "own folder, --work-dir; e.g. --out docs/results.md to replace the shipped page)",
    )
    parser.add_argument("--budget", default=None, help="one sentence stating the budget")
    parser.add_argument(
        "--datasets",
        nargs="*",
        default=None,
        help="datasets for the baselines (default: those of the runs; `--datasets none` or "
        "`--datasets` alone: no baselines)",
    )
    parser.add_argument("--protocols", nargs="*", default=list(PROTOCOLS))
    parser.add_argument(
        "--scored",
        nargs="*",
        type=Path,
        default=[],
        help="results.json of `python -m src.eval predictions=...` (one per protocol): models "
        "scored from a predictions file, shown beside the baselines",
    )
    parser.add_argument(
        "--target",
        action="append",
        default=[],
        metavar="DATASET=TOLERANCE",
        help="reproduction target per dataset, radians (default: "
        + ", ".join(f"{d}={t}" for d, t in TARGETS.items())
        + ")",
    )
    parser.add_argument(
        "--note",
        action="append",
        default=[],
        metavar="EXPERIMENT=TEXT",
        help="why a row is as it is (e.g. why it misses the target); printed with that row",
    )
    parser.add_argument(
        "--work-dir",
        type=Path,
        default=None,
        help="where the evaluations (and, without --out, the page) are written (default: a new "
        "outputs/report/<time>)",
    )
    parser.add_argument(
        "--records",
        type=Path,
        default=None,
        help="a folder of run records (docs/runs: the project's): the runs recorded there "
        "are on the page without their folders, and each run this report evaluates is recorded "
        "there (src/reporting/records.py)",
    )
    parser.add_argument(
        "--readme",
        type=Path,
        default=None,
        help="also put the headline table and figure between the results markers of this file",
    )
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    if not args.protocols:
        raise SystemExit("error: give at least one protocol")
    targets = dict(TARGETS)
    for item in args.target:
        dataset, _, value = item.partition("=")
        try:
            targets[dataset] = float(value)
        except ValueError:
            raise SystemExit(
                f"error: --target {item!r}: expected DATASET=TOLERANCE, e.g. h36m=0.03"
            ) from None
    if args.readme is not None:
        check_block(args.readme, "results")  # before hours of evaluation, not after
    # Read before anything is written: the page and README block change the tree.
    commit = git_commit()

    paths = discover_runs(args.runs)
    root = display_root(paths)
    runs = [load_run(path, root) for path in paths]
    # After the run folders: a folder given again replaces its record (and re-records it).
    if args.records is not None:
        given = [(record_name(r), r["path"]) for r in runs]
        runs += [
            r
            for r in read_records(args.records, args.protocols)
            if not any(record_name(r) == name and same_folder(r["path"], p) for name, p in given)
        ]
    # From the configs alone: a bad --note fails before evaluating.
    groups = page_order(group_runs(runs))
    notes = parse_notes(args.note, note_names(groups))
    scored = scored_entries(args.scored, args.protocols)  # read before anything is evaluated

    stamp = dt.datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    if args.work_dir is None:
        work = new_folder(PROJECT_ROOT / "outputs" / "report" / stamp).resolve()
    else:
        work = args.work_dir.resolve()
    kept = [r for g in groups for r in g.runs]
    fresh = [r for r in kept if not r.get("recorded")]
    for index, run in enumerate(fresh):
        evaluate_run(run, index, args.protocols, work)
        first = run["results"]["best"][args.protocols[0]]
        run["missing_files"] = first["provenance"]["missing_files"]
    datasets = sorted({g.dataset for g in groups})
    if args.datasets is not None:
        datasets = [d for d in args.datasets if d != "none"]
    baselines = evaluate_baselines(datasets, args.protocols, work, commit) + scored
    archives = Path(os.environ["MOTION_ARCHIVES"]) if os.environ.get("MOTION_ARCHIVES") else None
    mark_archives(fresh + baselines, archives)  # a record keeps the hash it was evaluated on
    if args.records is not None:
        date = dt.date.today().isoformat()
        for run in fresh:
            print(f"recorded {run['path']} as {write_record(run, args.records, commit, date)}")

    out = (args.out or work / "results.md").resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    figure = headline_figure(groups, args.protocols[0])
    figure_path = out.with_name(f"{out.stem}_errors.png")
    if figure is not None:
        figure.savefig(figure_path)
    command = shlex.join(["python", "-m", "src.report", *(sys.argv[1:] if argv is None else argv)])
    page = build_page(
        groups,
        baselines,
        args.protocols,
        command,
        args.budget,
        commit,
        targets,
        notes,
        figure_path.name if figure is not None else None,
    )
    replaced = out.exists()
    out.write_text(page)
    if args.readme is not None:
        here = args.readme.resolve().parent
        block = readme_block(
            groups,
            args.protocols[0],
            commit,
            targets,
            os.path.relpath(figure_path, here) if figure is not None else None,
            os.path.relpath(out, here),
        )
        replace_block(args.readme, "results", block)
    work.mkdir(parents=True, exist_ok=True)
    raw = {
        "groups": [
            {
                "label": g.label,
                "run_name": g.run_name,
                "dataset": g.dataset,
                "settings": g.settings,
                "left_out": g.left_out,
                "runs": g.runs,
            }
            for g in groups
        ],
        "baselines": baselines,
    }
    (work / "report.json").write_text(json.dumps(raw, indent=1, default=str))
    print(
        f"wrote {out}{' (replacing the file that was there)' if replaced else ''}"
        f"{f' and {figure_path.name}' if figure is not None else ''}; raw results in {work}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
