"""Write the results page (docs/results.md) from finished training runs.

    python -m src.report outputs/train/runs/li2018_cmu/<time> outputs/train/runs/... \
        --out docs/results.md --budget "1000 iterations on 2 CPU cores"

Every number on the page comes from evaluating the runs' checkpoints (and the baselines) here,
on the 8-window protocol of the papers and on 256 windows per action; nothing is typed in. Each
run's provenance (commit, data checksums and missing files, iterations, wall time, device) is
printed beside its numbers.
"""

from __future__ import annotations

import argparse
import datetime as dt
import hashlib
import json
import logging
import os
import sys
from pathlib import Path

import yaml

from src.lit.compose import compose_config
from src.lit.factory import PROJECT_ROOT, git_commit

log = logging.getLogger(__name__)

PROTOCOLS = {
    "srnn": "8 windows per action (SRNN seeds, the papers' protocol)",
    "random": "256 windows per action (fixed seed)",
}
BASELINES = ("zero_velocity", "running_avg_2", "running_avg_4")
ARCHIVES = {"h36m": "h3.6m.zip", "cmu": "cmu_mocap.zip"}


def sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def find_checkpoint(run: Path) -> Path:
    best = sorted((run / "checkpoints").glob("best-*.ckpt"))
    if best:
        return best[-1]
    last = run / "checkpoints" / "last.ckpt"
    if last.exists():
        return last
    raise SystemExit(f"error: {run} has no checkpoints/ (is it a finished training run?)")


def evaluate(overrides: list[str], out_dir: Path) -> dict:
    from src.eval import evaluate as run_eval

    cfg = compose_config("eval", overrides, out_dir)
    return run_eval(cfg)


def average_row(table: dict) -> dict[str, float]:
    return (table.get("average") or {}).get("values", {})


def fmt(value: float | None, decimals: int) -> str:
    return "-" if value is None else f"{value:.{decimals}f}"


def summary_table(entries: list[dict], metric: str, protocol: str) -> str:
    horizons = ["80", "160", "320", "400", "560", "1000"]
    decimals = 2 if metric == "euler" else 1
    lines = [
        "| run | dataset | iterations | " + " | ".join(f"{h} ms" for h in horizons) + " |",
        "|---|---|---:|" + "---:|" * len(horizons),
    ]
    for entry in entries:
        table = entry["results"][protocol]["tables"][0 if metric == "euler" else 1]
        avg = average_row(table)
        cells = [fmt(avg.get(h), decimals) for h in horizons]
        lines.append(
            f"| {entry['label']} | {entry['dataset']} | {entry.get('iterations', '-')} | "
            + " | ".join(cells)
            + " |"
        )
        published = table.get("published") or {}
        if metric == "euler" and published.get("average"):
            pub = published["average"]
            lines.append(
                f"| {entry['label']}: published ({table['published_label']}) | "
                f"{entry['dataset']} | paper | "
                + " | ".join(fmt(pub.get(h), 2) for h in horizons)
                + " |"
            )
    return "\n".join(lines)


def provenance_table(entries: list[dict]) -> str:
    lines = [
        "| run | commit | iterations | wall time | device | data archive (sha256) "
        "| missing files |",
        "|---|---|---:|---:|---|---|---|",
    ]
    for e in entries:
        missing = e.get("missing_files") or []
        missing_txt = f"{len(missing)} (see below)" if missing else "none"
        wall = e.get("wall_time_s")
        lines.append(
            f"| {e['label']} | {e.get('commit', '-')} | {e.get('iterations', '-')} | "
            f"{'-' if wall is None else f'{wall / 60:.1f} min'} | {e.get('device', '-')} | "
            f"{e.get('archive_sha256', '-')} | {missing_txt} |"
        )
    return "\n".join(lines)


def markdown_of(result: dict) -> str:
    from src.reporting.tables import ResultTable

    parts = []
    for t in result["tables"]:
        values = {a: {int(ms): v for ms, v in row.items()} for a, row in t["values"].items()}
        published = t.get("published")
        if published is not None:
            published = {a: {int(ms): v for ms, v in row.items()} for a, row in published.items()}
        parts.append(
            ResultTable(
                title=t["title"],
                metric=t["metric"],
                unit=t["unit"],
                actions=t["actions"],
                horizons_ms=t["horizons_ms"],
                values=values,
                absent=t["absent"],
                published=published,
                published_label=t.get("published_label"),
            ).to_markdown()
        )
    return "\n\n".join(parts)


def replace_block(path: Path, name: str, text: str) -> None:
    """Replace what lies between `<!-- name:start -->` and `<!-- name:end -->` in `path`."""
    content = path.read_text()
    start, end = f"<!-- {name}:start -->", f"<!-- {name}:end -->"
    if start not in content or end not in content:
        raise SystemExit(f"error: {path} has no {start} ... {end} markers")
    head, rest = content.split(start, 1)
    _, tail = rest.split(end, 1)
    path.write_text(f"{head}{start}\n{text}\n{end}{tail}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="*", type=Path, help="training run folders")
    parser.add_argument("--out", type=Path, default=PROJECT_ROOT / "docs" / "results.md")
    parser.add_argument("--budget", default=None, help="one sentence stating the budget")
    parser.add_argument(
        "--datasets",
        nargs="*",
        default=None,
        help="datasets for the baselines (default: those of the runs)",
    )
    parser.add_argument("--protocols", nargs="*", default=list(PROTOCOLS))
    parser.add_argument(
        "--work-dir",
        type=Path,
        default=None,
        help="where the evaluations write (default outputs/report/<time>)",
    )
    parser.add_argument(
        "--readme",
        type=Path,
        default=None,
        help="also put the summary table between the results markers of this file",
    )
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)

    stamp = dt.datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    work = args.work_dir or PROJECT_ROOT / "outputs" / "report" / stamp
    archives = Path(os.environ["MOTION_ARCHIVES"]) if os.environ.get("MOTION_ARCHIVES") else None

    entries: list[dict] = []
    datasets: list[str] = []
    for run in args.runs:
        run = run.resolve()
        summary = yaml.safe_load((run / "summary.yaml").read_text())
        config = yaml.safe_load((run / "config.yaml").read_text())
        dataset = config["data"]["name"]
        datasets.append(dataset)
        ckpt = find_checkpoint(run)
        entry = {
            "label": config.get("run_name", run.parent.name),
            "dataset": dataset,
            "run": str(run.relative_to(PROJECT_ROOT) if run.is_relative_to(PROJECT_ROOT) else run),
            "checkpoint": ckpt.name,
            **{k: summary.get(k) for k in ("iterations", "wall_time_s", "commit", "device")},
            "results": {},
        }
        for protocol in args.protocols:
            result = evaluate(
                [f"ckpt_path='{ckpt}'", f"protocol={protocol}"],
                work / f"{entry['label']}_{protocol}",
            )
            entry["results"][protocol] = result
            entry["missing_files"] = result["provenance"]["missing_files"]
        entries.append(entry)

    baseline_entries: list[dict] = []
    for dataset in args.datasets or sorted(set(datasets)):
        for model in BASELINES:
            entry = {"label": model, "dataset": dataset, "iterations": "-", "results": {}}
            for protocol in args.protocols:
                result = evaluate(
                    [
                        f"model={model}",
                        f"data={dataset}",
                        "data.allow_partial=true",
                        f"protocol={protocol}",
                    ],
                    work / f"{model}_{dataset}_{protocol}",
                )
                entry["results"][protocol] = result
                entry["missing_files"] = result["provenance"]["missing_files"]
            baseline_entries.append(entry)

    for entry in entries + baseline_entries:
        name = ARCHIVES.get(entry["dataset"])
        if archives is not None and name and (archives / name).exists():
            entry["archive_sha256"] = f"{name} {sha256(archives / name)[:16]}…"

    lines = [
        "# Results",
        "",
        f"Generated by `python -m src.report` on {dt.date.today()} at commit {git_commit()}; "
        "every number below was computed by that command from the listed runs' checkpoints and "
        "from the baselines. Do not edit by hand: re-run the command.",
        "",
        f"Command: `python -m src.report {' '.join(sys.argv[1:] if argv is None else argv)}`",
        "",
    ]
    if args.budget:
        lines += [f"**Budget.** {args.budget}", ""]
    lines += ["## Provenance", "", provenance_table(entries + baseline_entries), ""]
    missing = sorted({m for e in entries + baseline_entries for m in e.get("missing_files", [])})
    if missing:
        lines += [
            f"The data copy lacks {len(missing)} file(s) of the full archives; training used what "
            "exists (`data.allow_partial=true`) and actions without test files are shown as "
            "absent: " + ", ".join(f"`{m}`" for m in missing),
            "",
        ]
    for protocol in args.protocols:
        lines += [
            f"## Average over the evaluated actions: {PROTOCOLS.get(protocol, protocol)}",
            "",
            "Euler-angle error (radians):",
            "",
            summary_table(entries + baseline_entries, "euler", protocol),
            "",
            "MPJPE (mm on H3.6M, skeleton units on CMU):",
            "",
            summary_table(entries + baseline_entries, "mpjpe", protocol),
            "",
        ]
    lines += ["## Per-action tables", ""]
    for entry in entries + baseline_entries:
        for protocol in args.protocols:
            lines += [
                f"### {entry['label']} ({entry['dataset']}), {PROTOCOLS.get(protocol, protocol)}",
                "",
                markdown_of(entry["results"][protocol]),
                "",
            ]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines))
    if args.readme is not None:
        summary = [
            f"Average Euler-angle error over the evaluated actions, "
            f"{PROTOCOLS.get(args.protocols[0], args.protocols[0])}; generated on "
            f"{dt.date.today()} at commit {git_commit()}."
            + (f" Budget: {args.budget}" if args.budget else ""),
            "",
            summary_table(entries + baseline_entries, "euler", args.protocols[0]),
        ]
        replace_block(args.readme, "results", "\n".join(summary))
    (work / "report.json").write_text(json.dumps(entries + baseline_entries, indent=1, default=str))
    print(f"wrote {args.out} (raw results in {work})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
