"""Write the results page from finished training runs and run records.

    python -m src.report runs=[outputs/reproduce/multiruns/<time>] budget="..."
    python -m src.report runs=[<new runs>] records=docs/runs out=docs/results.md readme=README.md

Runs are found and evaluated (best and last checkpoints, each protocol) in src/reporting/runs.py
with the baselines, grouped by experiment, dataset and budget in groups.py, collected into one
long DataFrame in frame.py that decides the verdicts; page.py and claims.py lay out the page.
Every number comes from those evaluations and the published tables; nothing is typed in. With
records=DIR each run evaluated is also recorded there, and the runs recorded there join the
page without their folders: a page can grow over several machines, a few runs at a time.
"""

from __future__ import annotations

import datetime as dt
import json
import os
import shlex
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from src.cli import hydra_entry, silence_false_warnings
from src.lit.factory import PROJECT_ROOT, ConfigError, git_commit, register_resolvers
from src.reporting.frame import Results
from src.reporting.groups import group_runs, parse_notes
from src.reporting.headline import figures, readme_block
from src.reporting.page import build_page, per_action_csv, replace_block
from src.reporting.runs import (
    discover_runs,
    display_root,
    evaluate_baselines,
    evaluate_run,
    load_run,
    mark_archives,
    read_records,
    record_name,
    scored_entries,
    write_record,
)

register_resolvers()


def same_folder(a: str, b: str) -> bool:
    """Whether two shown paths name one run folder: each is relative to the root of the report
    that showed it, so the shorter ends the longer."""
    pa, pb = Path(a).parts, Path(b).parts
    n = min(len(pa), len(pb))
    return n > 0 and pa[-n:] == pb[-n:]


def _list(value) -> list:
    return [] if value is None else [value] if isinstance(value, str) else list(value)


@hydra_entry("report")
def main(cfg: DictConfig) -> int:
    silence_false_warnings()  # once, not once per evaluation
    if not (protocols := [str(p) for p in _list(cfg.protocols)]):
        raise ConfigError("protocols=[]: give at least one protocol, e.g. protocols=[srnn]")
    try:
        targets = {str(d): float(t) for d, t in cfg.targets.items()}
    except ValueError:
        raise ConfigError(
            f"targets={OmegaConf.to_container(cfg.targets)}: each a number of "
            "radians, e.g. targets.h36m=0.03"
        ) from None
    readme = Path(cfg.readme) if cfg.readme else None
    if readme:
        replace_block(readme, "results")  # before hours of evaluation, not after
    commit, work = git_commit(), Path(cfg.paths.output_dir)  # the commit before any write
    # The command as given: each evaluation below composes a config of its own.
    command = shlex.join(["python", "-m", "src.report", *HydraConfig.get().overrides.task])
    work.mkdir(parents=True, exist_ok=True)
    paths = discover_runs(_list(cfg.runs))
    root = display_root(paths) if paths else PROJECT_ROOT
    runs = [load_run(path, root) for path in paths]
    if cfg.records:  # a folder given again replaces its record
        given = [(record_name(r), r["path"]) for r in runs]
        runs += [
            r
            for r in read_records(Path(cfg.records), protocols)
            if not any(record_name(r) == name and same_folder(r["path"], p) for name, p in given)
        ]
    groups = group_runs(runs)
    notes = parse_notes([str(n) for n in _list(cfg.notes)], groups)  # before evaluating
    scored = scored_entries([Path(p) for p in _list(cfg.scored)], protocols)
    fresh = [r for g in groups for r in g.runs if not r.get("recorded")]
    for index, run in enumerate(fresh):
        evaluate_run(run, index, protocols, work)
    datasets = sorted({g.dataset for g in groups}) if cfg.datasets is None else cfg.datasets
    baselines = evaluate_baselines(datasets, protocols, work, commit) + scored
    archives = os.environ.get("MOTION_ARCHIVES")
    mark_archives(fresh + baselines, Path(archives) if archives else None)  # a record keeps its
    for run in fresh if cfg.records else ():
        path = write_record(run, Path(cfg.records), commit, dt.date.today().isoformat())
        print(f"recorded {run['path']} as {path}")

    results = Results(groups, baselines)
    out = Path(cfg.out or work / "results.md").resolve()
    tables = out.with_suffix("")  # docs/results.md: docs/results/<metric>_<protocol>.csv
    tables.mkdir(parents=True, exist_ok=True)
    for metric in ("euler", "mpjpe"):
        for protocol in protocols:
            (tables / f"{metric}_{protocol}.csv").write_text(
                per_action_csv(results, protocol, metric)
            )
    names = []
    for figure, kind in zip(figures(results, protocols[0]), ("errors", "validation"), strict=True):
        if figure is not None:
            figure.savefig(out.with_name(f"{out.stem}_{kind}.png"))
        names.append(f"{out.stem}_{kind}.png" if figure is not None else None)
    page = build_page(
        results, protocols, command, cfg.budget, commit, targets, notes, names, tables.name
    )
    replaced = out.exists()
    out.write_text(page)
    if readme:
        here = readme.resolve().parent
        figure = os.path.relpath(out.with_name(names[0]), here) if names[0] else None
        block = readme_block(
            results, protocols[0], commit, targets, figure, os.path.relpath(out, here)
        )
        replace_block(readme, "results", block)
    raw = {
        "groups": [
            {
                "label": g.label,
                "dataset": g.dataset,
                "iterations": g.iterations,
                "settings": g.settings,
                "runs": g.runs,
            }
            for g in groups
        ],
        "baselines": baselines,
    }
    (work / "report.json").write_text(json.dumps(raw, indent=1, default=str))
    results.frame.to_csv(work / "results_long.csv", index=False)
    print(
        f"wrote {out}{' (replacing the file that was there)' if replaced else ''}, its figures "
        f"and {tables.name}/*.csv; evaluations and the long table in {work}"
    )
    return 0


if __name__ == "__main__":
    main()
