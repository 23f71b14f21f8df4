"""Evaluating runs and baselines for the results page (src.report), as src.eval does.

Each run is evaluated twice: its best checkpoint (lowest validation error; validation runs on
the test windows, as in both reference implementations, so this selection uses test
information, protocol section 8) and its last checkpoint (no test information), on each
protocol. The baselines are evaluated on each dataset. The data archives are identified by
their sha256.
"""

from __future__ import annotations

import contextlib
import hashlib
import re
from pathlib import Path

from src.lit.compose import compose_config
from src.results import evaluate as run_eval

BASELINES = ("zero_velocity", "running_avg_2", "running_avg_4")
ARCHIVES = {"h36m": "h3.6m.zip", "cmu": "cmu_mocap.zip"}
SELECTIONS = ("best", "last")


def evaluate(overrides: list[str], out_dir: Path) -> dict:
    """One src.eval evaluation (its results.json as a dict), written into out_dir."""
    cfg = compose_config("eval", overrides, out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    # eval prints its tables; they are kept beside its results instead of on the console.
    with (out_dir / "stdout.txt").open("w") as fh, contextlib.redirect_stdout(fh):
        return run_eval(cfg)


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.=-]+", "_", name)


def evaluate_run(run: dict, index: int, protocols: list[str], work: Path) -> None:
    """Evaluate the run's best and last checkpoints on each protocol, into run["results"]."""
    run["results"] = {}
    checkpoints, iterations = run["checkpoints"], run["iterations_of"]
    same = checkpoints["last"] == checkpoints["best"] or (
        iterations["best"] is not None and iterations["best"] == iterations["last"]
    )
    for selection in SELECTIONS:
        if selection == "last" and same:
            run["results"]["last"] = run["results"]["best"]
            # One file for both means one was missing (find_checkpoints noted which), not that
            # the error was lowest at the end.
            if checkpoints["last"] != checkpoints["best"]:
                run["notes"].append("best = last (lowest error at the final validation)")
            continue
        run["results"][selection] = {}
        for protocol in protocols:
            print(f"evaluating {run['path']} ({selection}, {protocol})", flush=True)
            name = f"{index:03d}_{_safe(run['config'].get('run_name', 'run'))}_seed{run['seed']}"
            run["results"][selection][protocol] = evaluate(
                [f"ckpt_path='{run['checkpoints'][selection]}'", f"protocol={protocol}"],
                work / name / f"{selection}_{protocol}",
            )


def evaluate_baselines(
    datasets: list[str], protocols: list[str], work: Path, commit: str
) -> list[dict]:
    """Each baseline on each dataset and protocol: [{label, dataset, commit, results}]."""
    baselines = []
    for dataset in datasets:
        for model in BASELINES:
            entry = {"label": model, "dataset": dataset, "commit": commit, "results": {}}
            for protocol in protocols:
                print(f"evaluating {model} on {dataset} ({protocol})", flush=True)
                result = evaluate(
                    [
                        f"model={model}",
                        f"data={dataset}",
                        "data.allow_partial=true",
                        f"protocol={protocol}",
                    ],
                    work / "baselines" / f"{model}_{dataset}_{protocol}",
                )
                entry["results"][protocol] = result
                entry["missing_files"] = result["provenance"]["missing_files"]
            baselines.append(entry)
    return baselines


def sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def mark_archives(entries: list[dict], archives: Path | None) -> None:
    """Set each run's or baseline's `archive_sha256` ("h3.6m.zip 1a2b…") from the archive
    folder, where its dataset's archive is there; each archive is read once."""
    hashes: dict[str, str] = {}
    for entry in entries:
        dataset = entry["dataset"] if "dataset" in entry else entry["config"]["data"]["name"]
        name = ARCHIVES.get(dataset)
        if archives is not None and name and (archives / name).exists():
            if name not in hashes:
                hashes[name] = f"{name} {sha256(archives / name)[:16]}…"
            entry["archive_sha256"] = hashes[name]
