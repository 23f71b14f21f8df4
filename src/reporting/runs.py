"""src.report's runs: run folders, run records and scored predictions files. A record
(`<run_name>_seed<seed>_<config hash>.json`) holds what the page needs of an evaluated run, no
checkpoint, so that a page grows over machines: a report evaluates only the runs it is given."""

from __future__ import annotations

import functools
import hashlib
import json
import os
import re
from pathlib import Path

import pandas as pd
import yaml

from src.config import PROJECT_ROOT, ConfigError
from src.reporting.tables import LONG, read_long, read_results

AVERAGE_TAG = "val_euler/average/"  # the TensorBoard tags of the validations
ARCHIVES = {"h36m": "h3.6m.zip", "cmu": "cmu_mocap.zip"}
RECORD_FORMAT = 2
RECORD_KEYS = ("path", "config", "seed", "iterations_of", "iterations")
KEPT = "finished wall_time_s train_time_s commit device missing_files train_missing_files "
KEPT += "archive_sha256"


def _yaml(path: Path) -> dict:
    return yaml.safe_load(path.read_text()) if path.is_file() else {}


def _is_run(folder: Path) -> bool:
    # A multirun's .hydra/ folders hold a config.yaml too, but neither of the others.
    has = lambda name: (folder / name).exists()  # noqa: E731
    return has("config.yaml") and (has("checkpoints") or has("summary.yaml"))


def discover_runs(paths: list) -> list[Path]:
    """The run folders given or found under them, in sweep order (job 2 before 10), each once."""
    runs: list[Path] = []
    natural = lambda p: [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", str(p))]  # noqa: E731
    for path in (Path(p).resolve() for p in paths):
        if not path.exists():
            raise ConfigError(f"runs: {path} does not exist")
        found = [path] if _is_run(path) else []
        found = found or [p.parent for p in path.rglob("config.yaml") if _is_run(p.parent)]
        if not found:
            raise ConfigError(
                f"runs: no training run under {path}: a run folder holds config.yaml and "
                "checkpoints/ (is the run finished, and is this its folder?)"
            )
        runs += [r for r in sorted(found, key=natural) if r not in runs]
    return runs


def display_root(runs: list[Path]) -> Path:
    """The folder run folders are shown relative to: the project, or their common folder raised
    until each shows as <run_name>/<time> (two started in the same second must not read alike)."""
    runs = [Path(r).resolve() for r in runs]
    if all(r.is_relative_to(PROJECT_ROOT) for r in runs):
        return PROJECT_ROOT
    root = Path(os.path.commonpath(runs))
    while root.parent != root and any(len(r.relative_to(root).parts) < 2 for r in runs):
        root = root.parent
    return root


def find_checkpoints(run: Path) -> tuple[dict[str, Path], list[str]]:
    """({"best", "last"}: path, notes): summary.yaml's best (of all segments; in a moved folder by
    its name), else the newest best-*.ckpt, said in the notes; checkpoints/last.ckpt."""
    folder, notes, best, summary = run / "checkpoints", [], None, _yaml(run / "summary.yaml")
    if named := summary.get("best_checkpoint"):
        named = Path(named)
        places = (named, PROJECT_ROOT / named, folder / named.name)
        if (best := next((c for c in places if c.is_file()), None)) is None:
            notes.append(f"best checkpoint {named.name} of summary.yaml not found")
    elif not summary:
        notes.append("no summary.yaml (run unfinished or killed?)")
    if best is None and (local := sorted(folder.glob("best-*.ckpt"), key=os.path.getmtime)):
        best = local[-1]
        notes.append(f"best taken as this folder's {best.name}")
    last = folder / "last.ckpt" if (folder / "last.ckpt").is_file() else None
    if best is None and last is None:
        raise ConfigError(f"runs: {run} has no checkpoints (is it a finished training run?)")
    notes += ["no best checkpoint: best is last.ckpt"] if best is None else []
    notes += ["no last.ckpt: last is the best checkpoint"] if last is None else []
    return {"best": best or last, "last": last or best}, notes


def checkpoint_facts(path: Path) -> tuple[int | None, list[str]]:
    """Its iteration, and the files its data copy lacked in training (evaluations see test's)."""
    from src.lit.checkpoints import read_checkpoint

    ckpt = read_checkpoint(path)
    missing = list(ckpt.get("motion", {}).get("missing_files") or [])
    return ckpt.get("global_step"), missing


def validation_curve(run: Path) -> dict[int, dict[int, float]]:
    """{iterations done: {ms: average Euler error}} at each validation, from TensorBoard ({}
    without): logged at the step of the iteration before it (from 0), so after `step + 1`."""
    folder = Path(run) / "tensorboard"
    if not any(folder.glob("events.out.tfevents.*")):
        return {}
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(folder), size_guidance={"scalars": 0}).Reload()
    curve: dict[int, dict[int, float]] = {}
    for tag in events.Tags()["scalars"]:
        if tag.startswith(AVERAGE_TAG) and tag.endswith("ms"):
            ms = int(tag[len(AVERAGE_TAG) : -2])
            for event in events.Scalars(tag):  # a step logged twice: the later value
                curve.setdefault(event.step + 1, {})[ms] = float(event.value)
    return dict(sorted(curve.items()))


def load_run(path: Path, root: Path) -> dict:
    config, summary = _yaml(path / "config.yaml"), _yaml(path / "summary.yaml")
    checkpoints, notes = find_checkpoints(path)
    facts = {s: checkpoint_facts(p) for s, p in checkpoints.items()}
    shown = lambda p: str(p.relative_to(root) if p.is_relative_to(root) else p)  # noqa: E731
    return {
        "path": shown(path),
        # A resumed run's best checkpoint may lie in an earlier segment's folder: recorded as
        # shown where it is under `root`, as a record names no absolute path.
        "shown_checkpoints": {
            str(p): shown(p) for p in checkpoints.values() if p.is_relative_to(root)
        },
        "config": config,
        "seed": config.get("seed"),
        "checkpoints": checkpoints,
        "iterations_of": {s: iteration for s, (iteration, _) in facts.items()},
        "iterations": summary.get("iterations", facts["last"][0]),
        "finished": bool(summary),
        "notes": notes,
        "train_missing_files": facts["last"][1],
        "validations": validation_curve(path),
        **{k: summary.get(k) for k in ("wall_time_s", "train_time_s", "commit", "device")},
    }


def gather_runs(paths: list, records: Path | None, protocols: list[str]) -> list[dict]:
    """The runs of the folders given and of `records`; a folder given replaces its record."""
    folders = discover_runs(paths)
    root = display_root(folders) if folders else PROJECT_ROOT
    runs = [load_run(folder, root) for folder in folders]
    recorded = read_records(records, protocols) if records else []
    for run in runs:  # a run given again is written over its record
        run["record"] = next((r["record"] for r in recorded if same(run, r)), None)
    return runs + [r for r in recorded if not any(same(run, r) for run in runs)]


def same(run: dict, record: dict) -> bool:
    """One run: one name, and shown paths that end alike (each is relative to its root)."""
    ends = zip(Path(run["path"]).parts[::-1], Path(record["path"]).parts[::-1], strict=False)
    return record_name(run) == record_name(record) and all(a == b for a, b in ends)


def record_name(run: dict) -> str:
    """<run_name>_<dataset>_<iterations planned>_seed<seed>: a row's seed (groups.py)."""
    config = run["config"]
    name = f"{config.get('run_name', 'run')}_{config['data']['name']}_{config.get('iterations')}"
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", f"{name}_seed{run['seed']}")


def _portable(value):
    """`value` without absolute paths: each by its last part."""
    if isinstance(value, dict):
        return {k: _portable(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_portable(v) for v in value]
    if isinstance(value, str):
        key, eq, path = value.rpartition("=")
        if Path(path).is_absolute():
            return f"{key}{eq}.../{Path(path).name}"
    return value


def validation_rows(run: dict) -> pd.DataFrame:
    """The run's validations as LONG rows: checkpoint "validation", action "average"."""
    config, protocol = run["config"], run["config"]["data"].get("eval_protocol", "srnn")
    keys = (run["path"], config.get("run_name"), config["data"]["name"], run["seed"])
    rows = [
        (*keys, i, protocol, "validation", "euler", "average", ms, value, "")
        for i, errors in sorted((run.get("validations") or {}).items())
        for ms, value in sorted(errors.items())
    ]
    return pd.DataFrame(rows, columns=LONG)


def write_record(run: dict, folder: Path, commit: str, date: str) -> Path:
    """<name>.csv (the run's LONG rows, its validations too) and <name>.json (provenance)."""
    shown = run.get("shown_checkpoints", {})
    record = {
        "format": RECORD_FORMAT,
        "evaluated": {"commit": commit, "date": date},
        **{k: _portable(run[k]) for k in RECORD_KEYS},
        "checkpoints": {  # as shown where under the run folders' root, else in its own folder
            s: shown.get(str(p), f"{run['path']}/checkpoints/{Path(p).name}")
            for s, p in run.get("checkpoints", {}).items()
        },
        "notes": run.get("notes", []),
        **{k: run[k] for k in KEPT.split() if k in run},
    }
    path = Path(folder) / (run.get("record") or record_name(run))
    rows = pd.concat([run["rows"], validation_rows(run)], ignore_index=True)
    rows.to_csv(path.with_suffix(".csv"), index=False)
    path.with_suffix(".json").write_text(json.dumps(record, indent=1) + "\n")
    return path.with_suffix(".json")


def read_records(folder: Path, protocols: list[str]) -> list[dict]:
    """The runs recorded in `folder`, each with a note naming its record."""
    if not Path(folder).is_dir():
        raise ConfigError(
            f"records={folder} is not a folder; give the folder of run records (docs/runs holds "
            "the project's), or create it to start one"
        )
    runs = []
    for path in sorted(Path(folder).glob("*.json")):
        try:
            record = json.loads(path.read_text())
        except json.JSONDecodeError as err:
            raise ConfigError(f"{path} is not valid JSON ({err}): restore or remove it") from None
        if lacking := [k for k in ("format", *RECORD_KEYS) if k not in record]:
            raise ConfigError(
                f"{path} is not a run record (no {', '.join(lacking)}); only files written by "
                "`src.report records=...` belong in that folder"
            )
        if record["format"] != RECORD_FORMAT:
            raise ConfigError(
                f"{path} is a record of format {record['format']}, this version reads format "
                f"{RECORD_FORMAT}: evaluate its run again"
            )
        if not (table := path.with_suffix(".csv")).is_file():
            raise ConfigError(f"{path} has no {table.name} (its rows): restore it or remove both")
        rows = read_long(table)
        for selection in ("best", "last"):
            have = set(rows.protocol[rows.checkpoint == selection])
            if missing := [p for p in protocols if p not in have]:
                raise ConfigError(
                    f"{path} has no {selection}-checkpoint results for protocol "
                    f"{', '.join(missing)}: give protocols=[{','.join(sorted(have))}], or "
                    "evaluate its run folder again"
                )
        when = record["evaluated"]
        record["notes"] += [f"record {path.name}: evaluated at {when['commit']} on {when['date']}"]
        curve = rows[rows.checkpoint == "validation"]
        record["validations"] = {
            int(i): {int(ms): v for ms, v in zip(c.horizon, c.value, strict=True)}
            for i, c in curve.groupby("iterations")
        }
        record["rows"] = rows[rows.checkpoint != "validation"].reset_index(drop=True)
        runs.append({**record, "recorded": True, "record": path.stem})
    return runs


@functools.cache
def _sha256(path: Path) -> str:
    return f"{path.name} {hashlib.sha256(path.read_bytes()).hexdigest()[:16]}…"


def mark_archives(entries: list[dict], archives: Path | None) -> None:
    """Each entry's `archive_sha256` ("h3.6m.zip 1a2b…"), where its dataset's archive is."""
    for entry in entries:
        name = ARCHIVES.get(entry.get("dataset") or entry["config"]["data"]["name"])
        if archives is not None and name and (archives / name).exists():
            entry["archive_sha256"] = _sha256(archives / name)


def scored_entries(paths: list[Path], protocols: list[str]) -> list[dict]:
    """A row per model and dataset scored from predictions (its results.json of each protocol)."""
    entries: dict[tuple[str, str], dict] = {}
    for path in paths:
        result = read_results(path)
        prov = result.get("provenance", {})
        label, dataset = prov.get("model", Path(path).parent.name), prov.get("dataset", "?")
        entry = entries.setdefault(
            (label, dataset),
            {"label": label, "dataset": dataset, "kind": "predictions", "results": {}},
        )
        entry.update(commit=prov.get("commit", "-"), missing_files=prov.get("missing_files", []))
        entry.update(published=prov.get("published"))
        rows = read_long(Path(path).with_name("results_long.csv"))
        entry["results"][prov.get("eval_protocol", "srnn")] = rows.assign(checkpoint="-")
    for entry in entries.values():
        if lacking := [p for p in protocols if p not in entry["results"]]:
            raise ConfigError(
                f"scored: {entry['label']} ({entry['dataset']}) has no results for protocol "
                f"{', '.join(lacking)}: score its predictions with protocol={lacking[0]} too, or "
                f"give protocols=[{','.join(entry['results'])}]"
            )
    for entry in entries.values():
        entry["rows"] = pd.concat(entry.pop("results").values(), ignore_index=True)
    return list(entries.values())
