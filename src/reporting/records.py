"""Run records: a run's evaluations kept as one small JSON file, for `src.report --records`.

A results page is built from run folders, whose checkpoints are hundreds of MB each and live
on the machine that trained them. A record holds what the page needs of one run once it has
been evaluated (its config, seed, iterations, provenance and the src.eval results of its best
and last checkpoints on each protocol), and no checkpoint. So a page can grow over several
machines, a few runs at a time: each report evaluates only the runs it is given and reads the
others from their records, and the page names which rows came from a record and when those
were evaluated.

A record is named `<run_name>_seed<seed>_<config hash>.json`: the same run evaluated again
(or a run with the same configuration and seed) replaces it; any other run gets its own file.
"""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

from src.reporting.groups import identity

FORMAT = 1
KEYS = ("path", "config", "seed", "iterations_of", "iterations", "results")


def record_name(run: dict) -> str:
    ident = json.dumps(
        [run["config"].get("run_name"), run["config"]["data"]["name"], identity(run["config"])],
        sort_keys=True,
    )
    digest = hashlib.sha256(ident.encode()).hexdigest()[:10]
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", str(run["config"].get("run_name", "run")))
    return f"{name}_seed{run['seed']}_{digest}.json"


def _portable(value, run_path: str, shown: dict[str, str]):
    """`value` with no machine's absolute path: a checkpoint as the page shows it (`shown`:
    absolute path -> shown; else inside the run's shown folder), any other absolute path
    (data folders, Hydra's run folder) by its last part."""
    if isinstance(value, dict):
        out = {k: _portable(v, run_path, shown) for k, v in value.items()}
        ckpt = value.get("checkpoint")
        if isinstance(ckpt, str):
            out["checkpoint"] = shown.get(ckpt, f"{run_path}/checkpoints/{Path(ckpt).name}")
        return out
    if isinstance(value, list):
        return [_portable(v, run_path, shown) for v in value]
    if isinstance(value, str):
        key, eq, path = value.rpartition("=")  # an override, `paths.log_dir=/x/y`
        if Path(path).is_absolute():
            return f"{key}{eq}.../{Path(path).name}"
    return value


def write_record(run: dict, folder: Path, commit: str, date: str) -> Path:
    """Write the evaluated run's record into `folder` (read_records checked that it exists);
    returns its path."""
    record = {
        "format": FORMAT,
        "evaluated": {"commit": commit, "date": date},
        **{k: _portable(run[k], run["path"], run.get("shown_checkpoints", {})) for k in KEYS},
        "notes": run.get("notes", []),
        **{
            k: run[k]
            for k in (
                "finished",
                "wall_time_s",
                "train_time_s",
                "commit",
                "device",
                "missing_files",
                "train_missing_files",
                "archive_sha256",
                "validations",
            )
            if k in run
        },
    }
    path = folder / record_name(run)
    path.write_text(json.dumps(record, indent=1) + "\n")
    return path


def read_records(folder: Path, protocols: list[str]) -> list[dict]:
    """The runs recorded in `folder`, as src.report's run dicts (already evaluated), each
    with a note naming its record and when it was evaluated. Refuses, naming the file and the
    fix, a file that is not a record or lacks one of `protocols`."""
    if not folder.is_dir():
        raise SystemExit(
            f"error: --records {folder} is not a folder; give the folder of run records "
            "(docs/runs holds the project's), or create it to start one"
        )
    runs = []
    for path in sorted(folder.glob("*.json")):
        try:
            record = json.loads(path.read_text())
        except json.JSONDecodeError as err:
            raise SystemExit(
                f"error: {path} is not valid JSON ({err}): restore or remove it"
            ) from None
        lacking = [k for k in ("format", *KEYS) if not isinstance(record, dict) or k not in record]
        if lacking:
            raise SystemExit(
                f"error: {path} is not a run record (no {', '.join(lacking)}); only files "
                "written by `src.report --records` belong in that folder"
            )
        if record["format"] != FORMAT:
            raise SystemExit(
                f"error: {path} is a record of format {record['format']}, this version reads "
                f"format {FORMAT}: evaluate its run again"
            )
        for selection in ("best", "last"):
            missing = [p for p in protocols if p not in record["results"].get(selection, {})]
            if missing:
                raise SystemExit(
                    f"error: {path} has no {selection}-checkpoint results for protocol "
                    f"{', '.join(missing)}: give --protocols "
                    f"{' '.join(record['results'].get(selection, {}))}, or evaluate its run "
                    "folder again"
                )
        evaluated = record["evaluated"]
        record["notes"] = [
            *record.get("notes", []),
            f"record {path.name}: evaluated at {evaluated['commit']} on {evaluated['date']}",
        ]
        record["recorded"] = True
        if "validations" in record:  # JSON's keys are text: iterations and horizons again
            record["validations"] = {
                int(i): {int(ms): v for ms, v in errors.items()}
                for i, errors in record["validations"].items()
            }
        runs.append(record)
    return runs
