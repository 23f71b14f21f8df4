"""Finding finished training runs and loading each into a record (src.report); the scored
predictions files beside the baselines. Grouping the records: src/reporting/groups.py.

A run folder holds config.yaml beside checkpoints/ or summary.yaml (src.train's layout).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import yaml

from src.lit.factory import PROJECT_ROOT
from src.reporting.tensorboard import validation_curve
from src.results import read_results


# ---------------------------------------------------------------------------- finding runs
def is_run(folder: Path) -> bool:
    """A training run's folder: config.yaml beside checkpoints/ or summary.yaml (a multirun's
    .hydra/ folders also hold a config.yaml, but neither of the others)."""
    return (folder / "config.yaml").is_file() and (
        (folder / "checkpoints").is_dir() or (folder / "summary.yaml").is_file()
    )


def _natural(path: Path) -> list:
    """Sort key ordering `2_x` before `10_x` (a multirun's job numbers)."""
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", str(path))]


def discover_runs(paths: list[Path]) -> list[Path]:
    """The run folders given, or found under the folders given, in sweep order; each once."""
    runs: list[Path] = []
    for path in paths:
        path = path.resolve()
        if not path.exists():
            raise SystemExit(f"error: {path} does not exist")
        if is_run(path):
            found = [path]
        else:
            found = sorted(
                (
                    p.parent
                    for p in path.rglob("config.yaml")
                    if ".hydra" not in p.parts and is_run(p.parent)
                ),
                key=_natural,
            )
            if not found:
                raise SystemExit(
                    f"error: no training run under {path}: a run folder holds config.yaml and "
                    "checkpoints/ (is the run finished, and is this its folder?)"
                )
        runs += [r for r in found if r not in runs]
    return runs


def display_root(runs: list[Path]) -> Path:
    """The folder the page names run folders relative to, so that it shows no machine's
    absolute paths: the project for runs inside it (outputs/train/runs/...), else the runs'
    common folder, raised until each run shows as two parts at least (<run_name>/<time> in
    src.train's layout): for /x/out/<job>/train/runs/<name>/<time>, /x/out; for one run, or the
    segments of one resumed run, the run's <name> folder's parent."""
    runs = [Path(r).resolve() for r in runs]
    if not runs:
        return PROJECT_ROOT
    if all(r.is_relative_to(PROJECT_ROOT) for r in runs):
        return PROJECT_ROOT
    root = Path(os.path.commonpath(runs))
    # Not the time alone: two experiments' runs started in the same second would read alike.
    while root.parent != root and any(len(r.relative_to(root).parts) < 2 for r in runs):
        root = root.parent
    return root


def _load_yaml(path: Path) -> dict | None:
    return yaml.safe_load(path.read_text()) if path.is_file() else None


def find_checkpoints(run: Path) -> tuple[dict[str, Path], list[str]]:
    """({"best": path, "last": path}, notes) for a run folder.

    best is summary.yaml's best_checkpoint: the lowest validation error of the whole run,
    resumes included (it may lie in the folder of the run before a resume). When the run has
    no summary (unfinished or killed) or that file is gone, the run's own best-*.ckpt (the
    newest) stands in, and the notes say so. last is checkpoints/last.ckpt, the final iteration.
    """
    folder = run / "checkpoints"
    notes: list[str] = []
    summary = _load_yaml(run / "summary.yaml") or {}
    last = folder / "last.ckpt"
    best = None
    recorded = summary.get("best_checkpoint")
    if recorded:
        recorded = Path(recorded)
        # As written; relative to the project; or this folder's file of that name (a run folder
        # that was moved or copied).
        for candidate in (recorded, PROJECT_ROOT / recorded, folder / recorded.name):
            if candidate.is_file():
                best = candidate
                break
        else:
            notes.append(f"best checkpoint {recorded.name} of summary.yaml not found")
    elif not summary:
        notes.append("no summary.yaml (run unfinished or killed?)")
    if best is None:
        local = sorted(folder.glob("best-*.ckpt"), key=lambda p: p.stat().st_mtime)
        if local:
            best = local[-1]
            notes.append(f"best taken as this folder's {best.name}")
    if not last.is_file():
        last = None
    if best is None and last is None:
        raise SystemExit(f"error: {run} has no checkpoints (is it a finished training run?)")
    if best is None:
        notes.append("no best checkpoint: best is last.ckpt")
    if last is None:
        notes.append("no last.ckpt: last is the best checkpoint")
    return {"best": best or last, "last": last or best}, notes


def checkpoint_facts(path: Path) -> tuple[int | None, list[str]]:
    """The checkpoint's training iteration, and the files the run's data copy lacked when it
    trained (training and test files; an evaluation of the checkpoint sees only the test
    files). One read of the file for both.

    The report's only direct use of the checkpoint loading API: the evaluations load their
    checkpoints through src.eval."""
    from src.lit.checkpoints import read_checkpoint

    ckpt = read_checkpoint(path)
    iteration = ckpt["state_dict"].get("iteration")
    missing = list(ckpt.get("motion", {}).get("missing_files") or [])
    return None if iteration is None else int(iteration), missing


def load_run(path: Path, root: Path | None = None) -> dict:
    """The record of one run folder: its config, checkpoints and their facts, its summary.
    `path` in the record is relative to `root` (display_root) when given."""
    config = _load_yaml(path / "config.yaml")
    # Runs of older versions may lack run_name: their folder is runs/<name>/<time>.
    config.setdefault("run_name", path.parent.name)
    summary = _load_yaml(path / "summary.yaml") or {}
    checkpoints, notes = find_checkpoints(path)
    facts = {s: checkpoint_facts(p) for s, p in checkpoints.items()}
    iterations_of = {s: iteration for s, (iteration, _) in facts.items()}
    root = root or PROJECT_ROOT

    def shown(p: Path) -> str:
        return str(p.relative_to(root) if p.is_relative_to(root) else p)

    return {
        "path": shown(path),
        # Only to tell a resumed run's earlier segments (their ckpt_path) apart from copies.
        "folder": str(path.resolve()),
        # A resumed run's best checkpoint may lie in an earlier segment's folder. Only those
        # under `root`: a record names no absolute path.
        "shown_checkpoints": {
            str(p): shown(p) for p in checkpoints.values() if p.is_relative_to(root)
        },
        "config": config,
        "seed": config.get("seed"),
        "checkpoints": checkpoints,
        "iterations_of": iterations_of,
        "iterations": summary.get("iterations", iterations_of["last"]),
        "finished": bool(summary),
        "notes": notes,
        "train_missing_files": facts["last"][1],
        # This folder's own validations; a resumed run gets its earlier segments' in groups.py.
        "validations": validation_curve(path),
        **{k: summary.get(k) for k in ("wall_time_s", "train_time_s", "commit", "device")},
    }


def scored_entries(paths: list[Path], protocols: list[str]) -> list[dict]:
    """Rows beside the baselines for models scored from a predictions file (`python -m src.eval
    predictions=...`): one per model and dataset, from the results.json of each protocol."""
    entries: dict[tuple[str, str], dict] = {}
    for path in paths:
        try:
            result = read_results(path)
        except ValueError as err:  # read_results' ConfigError: not a results.json
            raise SystemExit(f"error: --scored {err}") from None
        prov = result.get("provenance", {})
        label, dataset = prov.get("model", path.parent.name), prov.get("dataset", "?")
        entry = entries.setdefault(
            (label, dataset),
            {"label": label, "dataset": dataset, "kind": "predictions", "results": {}},
        )
        entry.update(commit=prov.get("commit", "-"), missing_files=prov.get("missing_files", []))
        entry["results"][prov.get("eval_protocol", "srnn")] = result
    for entry in entries.values():
        lacking = [p for p in protocols if p not in entry["results"]]
        if lacking:
            raise SystemExit(
                f"error: --scored {entry['label']} ({entry['dataset']}) has no results for "
                f"protocol {', '.join(lacking)}: score its predictions with protocol="
                f"{lacking[0]} too, or pass --protocols {' '.join(entry['results'])}"
            )
    return list(entries.values())
