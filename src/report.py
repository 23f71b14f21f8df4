"""The results page from finished training runs and run records (src/reporting/):

    python -m src.report runs=[<new runs>] records=docs/runs out=docs/results.md readme=README.md

Each run's best and last checkpoints and the baselines are evaluated as src.eval does, on each
protocol; every number on the page comes from those evaluations, the records of runs evaluated
before (records=DIR, where each run evaluated here is recorded) and the papers.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import itertools
import os
import re
import shlex
from pathlib import Path

import pandas as pd
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from src.cli import git_commit, hydra_entry, silence_false_warnings
from src.config import ConfigError
from src.prepare import compose_config
from src.reporting.frame import Results
from src.reporting.groups import group_runs, parse_notes
from src.reporting.page import replace_block, write_page
from src.reporting.runs import gather_runs, mark_archives, scored_entries, write_record
from src.reporting.tables import read_long
from src.results import evaluate as run_eval

BASELINES = ("zero_velocity", "running_avg_2", "running_avg_4")


def evaluate(overrides: list[str], out_dir: Path):
    """(results.json as a dict, its long rows) of src.eval into out_dir, its tables in a file."""
    cfg = compose_config("eval", overrides, out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with (out_dir / "stdout.txt").open("w") as fh, contextlib.redirect_stdout(fh):
        result = run_eval(cfg)
    return result, read_long(out_dir / "results_long.csv")


def evaluate_run(run: dict, index: int, protocols: list[str], work: Path) -> None:
    checkpoints, iterations = run["checkpoints"], run["iterations_of"]
    name = re.sub(r"[^A-Za-z0-9_.=-]+", "_", str(run["config"].get("run_name", "run")))
    same = checkpoints["last"] == checkpoints["best"]
    one = same or (iterations["best"] is not None and iterations["best"] == iterations["last"])
    # One file for both means one was missing (find_checkpoints said which), not that the error
    # was lowest at the end.
    if one and not same:
        run["notes"].append("best = last (lowest error at the final validation)")
    rows, missing = [], []
    for selection in ("best",) if one else ("best", "last"):
        for protocol in protocols:
            print(f"evaluating {run['path']} ({selection}, {protocol})", flush=True)
            result, found = evaluate(
                [f"ckpt_path='{checkpoints[selection]}'", f"protocol={protocol}"],
                work / f"{index:03d}_{name}_seed{run['seed']}" / f"{selection}_{protocol}",
            )
            keys = {"run": run["path"], "seed": run["seed"], "checkpoint": selection}
            rows.append(found.assign(iterations=iterations[selection], **keys))
            missing = missing or result["provenance"]["missing_files"]
    rows += [r.assign(checkpoint="last", iterations=iterations["last"]) for r in rows if one]
    run["rows"], run["missing_files"] = pd.concat(rows, ignore_index=True), missing


def evaluate_baselines(datasets, protocols: list[str], work: Path, commit: str) -> list[dict]:
    baselines = []
    for dataset, model in itertools.product(datasets, BASELINES):
        rows = []
        for protocol in protocols:
            print(f"evaluating {model} on {dataset} ({protocol})", flush=True)
            overrides = [f"model={model}", f"data={dataset}", f"protocol={protocol}"]
            folder = work / "baselines" / f"{model}_{dataset}_{protocol}"
            result, found = evaluate([*overrides, "data.allow_partial=true"], folder)
            rows.append(found)
        prov = result["provenance"]
        entry = {"label": model, "dataset": dataset, "commit": commit, "rows": pd.concat(rows)}
        baselines.append(
            entry | {"missing_files": prov["missing_files"], "published": prov["published"]}
        )
    return baselines


def _list(value) -> list:
    return [] if value is None else [value] if isinstance(value, str) else list(value)


@hydra_entry("report", tidy=False)  # never undo hours of evaluations
def main(cfg: DictConfig) -> int:
    silence_false_warnings()  # once, not once per evaluation
    if not (protocols := [str(p) for p in _list(cfg.protocols)]):
        raise ConfigError("protocols=[]: give at least one protocol, e.g. protocols=[srnn]")
    try:
        targets = {str(d): float(t) for d, t in cfg.targets.items()}
    except ValueError:
        shown = OmegaConf.to_container(cfg.targets)
        message = f"targets={shown}: each a number of radians, e.g. targets.h36m=0.03"
        raise ConfigError(message) from None
    readme, records = (Path(x) if x else None for x in (cfg.readme, cfg.records))
    if readme:
        replace_block(readme, "results")  # before hours of evaluation, not after
    commit, work = git_commit(), Path(cfg.paths.output_dir)  # the commit before any write
    # The command as given: each evaluation below composes a config of its own.
    command = shlex.join(["python", "-m", "src.report", *HydraConfig.get().overrides.task])
    work.mkdir(parents=True, exist_ok=True)
    groups = group_runs(gather_runs(_list(cfg.runs), records, protocols))
    notes = parse_notes([str(n) for n in _list(cfg.notes)], groups)  # before evaluating
    scored = scored_entries([Path(p) for p in _list(cfg.scored)], protocols)
    fresh = [r for g in groups for r in g.runs if not r.get("recorded")]
    for index, run in enumerate(fresh):
        evaluate_run(run, index, protocols, work)
    datasets = sorted({g.dataset for g in groups}) if cfg.datasets is None else cfg.datasets
    baselines = evaluate_baselines(datasets, protocols, work, commit) + scored
    archives = os.environ.get("MOTION_ARCHIVES")  # a record keeps the hash it was evaluated on
    mark_archives(fresh + baselines, Path(archives) if archives else None)
    for run in fresh if records else ():
        path = write_record(run, records, commit, dt.date.today().isoformat())
        print(f"recorded {run['path']} as {path}")
    results = Results(groups, baselines)
    out = Path(cfg.out or work / "results.md").resolve()
    replaced = out.exists()
    write_page(results, out, protocols, command, cfg.budget, commit, targets, notes, readme)
    results.frame.to_csv(work / "results_long.csv", index=False)
    print(
        f"wrote {out}{' (replacing the file that was there)' if replaced else ''}, its figures "
        f"and {out.stem}/*.csv; evaluations and the long table in {work}"
    )
    return 0


if __name__ == "__main__":
    main()
