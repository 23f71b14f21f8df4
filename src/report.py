"""Write the results page (docs/results.md) from finished training runs.

    python -m src.report outputs/reproduce/multiruns/<time> --budget "4000 iterations on a GPU"
    python -m src.report outputs/train/runs/li2018_cmu/<time> outputs/train/runs/... \
        --out docs/results.md --readme README.md

Arguments are run folders (config.yaml, summary.yaml, checkpoints/) or folders holding them,
such as a multirun of `python -m src.train -m reproduce=papers`. Runs are grouped by experiment
(run_name) and dataset; runs of one group that differ only in their seed are aggregated as mean
± std over the seeds. Each run is evaluated twice: its best checkpoint (lowest validation error;
validation runs on the test windows, as in both reference implementations, so this selection
uses test information, protocol section 8) and its last checkpoint (no test information).

Every number on the page comes from evaluating the checkpoints (and the baselines) here, on the
8-window protocol of the papers and on 256 windows per action; nothing is typed in. Published
averages are printed twice: recomputed from the paper's per-action values over the actions
evaluated here (like for like when the data copy lacks some), and as printed in the paper.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import hashlib
import json
import logging
import os
import re
import shlex
import sys
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from src.lit.compose import compose_config
from src.lit.factory import PROJECT_ROOT, git_commit
from src.lit.runs import COMPUTES
from src.reporting.published import known_slips, published_beside, published_for
from src.reporting.tables import (
    SeedTable,
    Stat,
    fmt,
    printed_scope,
    same_set_average,
    table_from_dict,
)

log = logging.getLogger(__name__)

PROTOCOLS = {
    "srnn": "8 windows per action (SRNN seeds, the papers' protocol)",
    "random": "256 windows per action (fixed seed)",
}
BASELINES = ("zero_velocity", "running_avg_2", "running_avg_4")
ARCHIVES = {"h36m": "h3.6m.zip", "cmu": "cmu_mocap.zip"}
HORIZONS = (80, 160, 320, 400, 560, 1000)
SELECTIONS = ("best", "last")
SELECTION_LABELS = {"best": "best (test-selected)", "last": "last (no test info)"}
# The project's reproduction target: ours within this much (radians) of the published
# same-set average at every published horizon. Override with --target DATASET=TOLERANCE.
TARGETS = {"h36m": 0.03, "cmu": 0.05}

# Published numbers for experiments whose model config's own entry (Li et al.'s full model)
# is not theirs: the ablations of Tables 5 and 6 (averages only), and Figure 4's window sizes
# and runs without the regulariser, for which the paper prints no numbers (None).
EXPERIMENT_PUBLISHED: dict[str, dict | None] = {
    "li2018_h36m_no_long_term": {
        "paper": "li2018",
        "table": 5,
        "method": "conv_s2s_without_long_term",
    },
    "li2018_h36m_kernel_4x4": {"paper": "li2018", "table": 6, "method": "kernel_4x4"},
    "li2018_h36m_kernel_7x2": {"paper": "li2018", "table": 6, "method": "kernel_7x2"},
    "li2018_h36m_C5": None,
    "li2018_h36m_C10": None,
    "li2018_h36m_C5_no_adv": None,
    "li2018_h36m_C10_no_adv": None,
    "li2018_h36m_C20_no_adv": None,
}

# Config keys that do not make two runs different experiments: the seed, where files live,
# the device, and how often files are written or progress printed (with torch.compile, the
# settings src.lit.runs lets a resume change because they do not change what a run computes).
# A resumed run is the run it continues: `resume` and `ckpt_path` name where it came from.
IGNORED_KEYS = (
    "seed",
    "data.seed",
    "ckpt_path",
    "resume",
    "checkpoint_every",
    "media_every",
    "progress_every_s",
    "task_name",
)
IGNORED_PREFIXES = (
    "paths.",
    "trainer.",
    "compile.",
    "hydra.",
    "data.data_dir",
    "data.archive_dir",
    "data.archive",
    "data.num_workers",
    "data.eval_batch_size",
)


def sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


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
            notes.append(f"best checkpoint {recorded} of summary.yaml not found")
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


def find_checkpoint(run: Path) -> Path:
    """The run's best checkpoint (see find_checkpoints)."""
    return find_checkpoints(run)[0]["best"]


def checkpoint_facts(path: Path) -> tuple[int | None, list[str]]:
    """The checkpoint's training iteration, and the files the run's data copy lacked when it
    trained (training and test files; an evaluation of the checkpoint sees only the test
    files). One read of the file for both."""
    from src.lit.checkpoints import read_checkpoint

    ckpt = read_checkpoint(path)
    iteration = ckpt["state_dict"].get("iteration")
    missing = list(ckpt.get("motion", {}).get("missing_files") or [])
    return None if iteration is None else int(iteration), missing


# ---------------------------------------------------------------------------- grouping
def _flatten(config: dict, prefix: str = "") -> dict[str, str]:
    out: dict[str, str] = {}
    for key, value in config.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(_flatten(value, f"{name}."))
        else:
            out[name] = json.dumps(value)
    return out


def identity(config: dict) -> dict[str, str]:
    """What makes a run the experiment it is: its config less seed, paths, device, logging."""
    return {
        k: v
        for k, v in _flatten(config).items()
        if k not in IGNORED_KEYS
        # Trainer keys that change the numbers make another setting, not another seed.
        and (not k.startswith(IGNORED_PREFIXES) or k.startswith(COMPUTES))
    }


@dataclass
class Group:
    """Runs of one experiment on one dataset that differ only in their seed."""

    label: str
    run_name: str
    dataset: str
    runs: list[dict] = field(default_factory=list)


def group_runs(runs: list[dict]) -> list[Group]:
    """Group run records ({"config": ..., ...}) by run_name, dataset and configuration, in order
    of first appearance. Runs sharing a run_name but differing in another setting (a budget, a
    switch) are separate groups, labelled with the settings that tell them apart."""
    by_key: dict[tuple, list[dict]] = {}
    for run in runs:
        config = run["config"]
        ident = identity(config)
        key = (config.get("run_name"), config["data"]["name"], tuple(sorted(ident.items())))
        by_key.setdefault(key, []).append(run)
    groups = []
    for (run_name, dataset, ident), members in by_key.items():
        siblings = [dict(k[2]) for k in by_key if k[:2] == (run_name, dataset)]
        label = str(run_name)
        if len(siblings) > 1:
            mine = dict(ident)
            keys = sorted(
                k
                for k in {k for s in siblings for k in s}
                if len({s.get(k, "null") for s in siblings}) > 1
            )
            label += " (" + ", ".join(f"{k}={json.loads(mine.get(k, 'null'))}" for k in keys) + ")"
        groups.append(Group(label, str(run_name), str(dataset), members))
    return groups


# ---------------------------------------------------------------------------- evaluation
def evaluate(overrides: list[str], out_dir: Path) -> dict:
    from src.eval import evaluate as run_eval

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


def load_run(path: Path) -> dict:
    config = _load_yaml(path / "config.yaml")
    # Runs of older versions may lack run_name: their folder is runs/<name>/<time>.
    config.setdefault("run_name", path.parent.name)
    summary = _load_yaml(path / "summary.yaml") or {}
    checkpoints, notes = find_checkpoints(path)
    facts = {s: checkpoint_facts(p) for s, p in checkpoints.items()}
    iterations_of = {s: iteration for s, (iteration, _) in facts.items()}
    train_missing = facts["last"][1]
    shown = path.relative_to(PROJECT_ROOT) if path.is_relative_to(PROJECT_ROOT) else path
    return {
        "path": str(shown),
        "config": config,
        "seed": config.get("seed"),
        "checkpoints": checkpoints,
        "iterations_of": iterations_of,
        "iterations": summary.get("iterations", iterations_of["last"]),
        "notes": notes,
        "train_missing_files": train_missing,
        **{k: summary.get(k) for k in ("wall_time_s", "commit", "device")},
    }


def scored_entries(paths: list[Path], protocols: list[str]) -> list[dict]:
    """Rows beside the baselines for models scored from a predictions file (`python -m src.eval
    predictions=...`): one per model and dataset, from the results.json of each protocol."""
    from src.plot_errors import read_results

    entries: dict[tuple[str, str], dict] = {}
    for path in paths:
        try:
            result = read_results(path)
        except ValueError as err:  # plot_errors' ConfigError: not a results.json
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


# ---------------------------------------------------------------------------- the page
def _table_index(metric: str) -> int:
    return 0 if metric == "euler" else 1


def run_published(group: Group, result: dict) -> tuple[dict | None, str | None]:
    """Published values for a group's tables: the report's own entry for the experiments of
    EXPERIMENT_PUBLISHED, else those the evaluation printed (the checkpoint's model config),
    and only on the dataset they were published for."""
    if group.run_name in EXPERIMENT_PUBLISHED:
        return published_for(EXPERIMENT_PUBLISHED[group.run_name], group.dataset)
    table = result["tables"][0]
    return _published_of(table, group.dataset), table.get("published_label")


def _published_of(table: dict, dataset: str) -> dict[str, dict[int, float]] | None:
    """A stored result table's published values (ms keys back to int), if on their dataset."""
    published = published_beside(table, dataset)
    if not published:
        return None
    return {a: {int(ms): float(v) for ms, v in row.items()} for a, row in published.items()}


def seed_table(group: Group, selection: str, protocol: str, metric: str) -> SeedTable:
    results = [run["results"][selection][protocol] for run in group.runs]
    published, label = run_published(group, results[0]) if metric == "euler" else (None, None)
    tables = [table_from_dict(r["tables"][_table_index(metric)]) for r in results]
    title = (
        f"{group.label} on {group.dataset}, {SELECTION_LABELS[selection]} checkpoint, "
        f"{PROTOCOLS.get(protocol, protocol)}"
    )
    return SeedTable(title, tables, published, label)


def _range(values: list[int | None]) -> str:
    known = sorted({v for v in values if v is not None})
    if not known:
        return "-"
    if len(known) == 1:
        return f"{known[0]:,}"
    return f"{known[0]:,}–{known[-1]:,}"


def _stat_cells(average: dict[int, Stat] | None, decimals: int) -> list[str]:
    average = average or {}
    return [average[ms].format(decimals) if ms in average else "-" for ms in HORIZONS]


def summary_table(groups: list[Group], baselines: list[dict], metric: str, protocol: str) -> str:
    decimals = 2 if metric == "euler" else 1
    lines = [
        "| experiment | dataset | checkpoint | seeds | iterations | "
        + " | ".join(f"{h} ms" for h in HORIZONS)
        + " |",
        "|---|---|---|---:|---:|" + "---:|" * len(HORIZONS),
    ]
    for group in groups:
        table = None
        for selection in SELECTIONS:
            table = seed_table(group, selection, protocol, metric)
            if selection == "best":
                best = _range([r["iterations_of"]["best"] for r in group.runs])
                iterations = f"{best} of {_range([r['iterations'] for r in group.runs])}"
            else:
                iterations = _range([r["iterations"] for r in group.runs])
            lines.append(
                f"| {group.label} | {group.dataset} | {SELECTION_LABELS[selection]} | "
                f"{table.n} | {iterations} | "
                + " | ".join(_stat_cells(table.average(), decimals))
                + " |"
            )
        if metric == "euler" and table is not None and table.published is not None:
            lines += _published_rows(group.label, group.dataset, table)
    for entry in baselines:
        result = entry["results"][protocol]
        table_dict = result["tables"][_table_index(metric)]
        published = _published_of(table_dict, entry["dataset"]) if metric == "euler" else None
        table = SeedTable(
            entry["label"],
            [table_from_dict(table_dict)],
            published,
            table_dict.get("published_label"),
        )
        lines.append(
            f"| {entry['label']} | {entry['dataset']} | - | - | - | "
            + " | ".join(_stat_cells(table.average(), decimals))
            + " |"
        )
        if table.published is not None:
            lines += _published_rows(entry["label"], entry["dataset"], table)
    return "\n".join(lines)


def _published_rows(label: str, dataset: str, table: SeedTable) -> list[str]:
    rows = []
    same, printed = table.published_same_set(), table.published_as_printed()
    name = table.published_label or "published"
    slips = known_slips(table.published_label, table.evaluated)
    flag = f" (includes slips of the paper: {', '.join(slips)})" if slips else ""
    for text, values in (
        (f"published ({name}), same {len(table.evaluated)} actions{flag}", same),
        (f"published ({name}), as printed ({printed_scope(table.published)})", printed),
    ):
        if values:
            rows.append(
                f"| {label}: {text} | {dataset} | paper | - | paper | "
                + " | ".join(fmt(values.get(ms), 2) for ms in HORIZONS)
                + " |"
            )
    return rows


def training_files(config: dict, actions: list[str], missing: list[str]) -> dict[str, tuple]:
    """{action: (present, expected)} training files of each action in the run's data copy; {}
    for datasets without a file list (synthetic)."""
    from src.data.layout import H36M_TRAIN_SUBJECTS, cmu_files, h36m_files

    data = config.get("data", {})
    if data.get("name") == "h36m":
        entries = h36m_files(data.get("train_subjects", H36M_TRAIN_SUBJECTS), actions, "train")
    elif data.get("name") == "cmu":
        entries = cmu_files(actions, "train")
    else:
        return {}
    gone, out = set(missing), {}
    for entry in entries:
        present, expected = out.get(entry.action, (0, 0))
        out[entry.action] = (present + (entry.relpath not in gone), expected + 1)
    return out


def _printed_gap(ours: float, published: float) -> float:
    """Ours minus published as a reader of the tables computes it: from the printed values."""
    return round(round(ours, 2) - round(published, 2), 2)


def _beyond(ours: dict[int, float], published: dict[int, float], target: float) -> list[int]:
    """Horizons where ours is further than `target` from published, compared at the printed
    precision, as a reader of the tables would."""
    return [
        ms
        for ms in HORIZONS
        if ms in published and abs(_printed_gap(ours[ms], published[ms])) > target
    ]


def _signed(difference: float) -> str:
    """A difference at the printed precision; one that rounds to zero has no sign (+0.00, not
    -0.00)."""
    return f"{round(difference, 2) + 0.0:+.2f}"


def _gap_text(ours: dict[int, float], published: dict[int, float], target: float | None) -> str:
    # The gap that the verdict judges; the unrounded difference can print one unit apart from
    # it (+0.03 beside "NOT within the target of 0.03").
    cells = [
        f"{ms} ms {_signed(_printed_gap(ours[ms], published[ms]))}"
        for ms in HORIZONS
        if ms in published
    ]
    text = ", ".join(cells)
    if target is not None:
        beyond = [f"{ms} ms" for ms in _beyond(ours, published, target)]
        text += (
            f": within the target of {target:.2f} at every horizon"
            if not beyond
            else f": NOT within the target of {target:.2f} at {', '.join(beyond)}"
        )
    return text


def _mean_average(table: SeedTable) -> dict[int, float]:
    """The average row's mean over seeds per horizon; {} where an action has no values."""
    return {ms: stat.mean for ms, stat in (table.average() or {}).items()}


def gap_lines(group: Group, selection: str, protocol: str, target: float | None) -> list[str]:
    """Ours minus the published same-set average, per horizon (Euler, mean over seeds), with
    the verdict against the target; then the same over the actions that have training data in
    this copy, where some evaluated action has none."""
    table = seed_table(group, selection, protocol, "euler")
    same, average = table.published_same_set(), _mean_average(table)
    if not same or not average:
        return []
    where = f"({PROTOCOLS.get(protocol, protocol)})"
    label = table.published_label
    lines = [
        f"- {SELECTION_LABELS[selection]} minus published ({label}) over the same "
        f"{len(table.evaluated)} actions {where}: " + _gap_text(average, same, target) + "."
    ]
    files = training_files(group.runs[0]["config"], table.evaluated, _missing(group))
    trained = [a for a in table.evaluated if files.get(a, (1, 1))[0] > 0]
    if files and len(trained) < len(table.evaluated):
        ours = {
            ms: sum(table.stats(a)[ms].mean for a in trained) / len(trained)
            for ms in table.horizons_ms
        }
        theirs = same_set_average(table.published, trained, table.horizons_ms)
        untrained = [a for a in table.evaluated if a not in trained]
        lines.append(
            f"- The same over the {len(trained)} evaluated actions that have training files in "
            f"this data copy (without {', '.join(untrained)}): "
            + _gap_text(ours, theirs, None)
            + "."
        )
    return lines


def comparison_lines(groups: list[Group], protocol: str) -> list[str]:
    """Runs of one experiment that differ in a setting (a reference switch, a budget, the
    training length of the future): each later group's Euler average minus the first group's,
    per horizon and checkpoint selection, on the horizons both have."""
    siblings: dict[tuple[str, str], list[Group]] = {}
    for group in groups:
        siblings.setdefault((group.run_name, group.dataset), []).append(group)
    lines = []
    for base, *others in (members for members in siblings.values() if len(members) > 1):
        for other in others:
            for selection in SELECTIONS:
                a = seed_table(base, selection, protocol, "euler")
                b = seed_table(other, selection, protocol, "euler")
                head = f"- {other.label} minus {base.label}, {SELECTION_LABELS[selection]}"
                if a.evaluated != b.evaluated:
                    lines.append(f"{head}: not compared, they were evaluated on other actions.")
                    continue
                mean_a, mean_b = _mean_average(a), _mean_average(b)
                common = [ms for ms in HORIZONS if ms in mean_a and ms in mean_b]
                cells = ", ".join(f"{ms} ms {_signed(mean_b[ms] - mean_a[ms])}" for ms in common)
                lines.append(f"{head} (seeds: {b.n} and {a.n}): {cells}.")
    return lines


def _missing(group: Group) -> list[str]:
    keys = ("missing_files", "train_missing_files")
    return sorted({m for r in group.runs for k in keys for m in r.get(k) or []})


def training_data_line(group: Group, protocol: str) -> str | None:
    """Which evaluated actions were trained on fewer files than the full archive holds."""
    table = seed_table(group, "best", protocol, "euler")
    files = training_files(group.runs[0]["config"], table.evaluated, _missing(group))
    short = [f"{a} {p} of {n}" for a, (p, n) in files.items() if p < n]
    if not short:
        return None
    return (
        "- Training files of the evaluated actions that this data copy lacks in part or whole "
        "(files present of the full archive's): " + ", ".join(short) + "."
    )


def slip_line(group: Group, protocol: str) -> str | None:
    table = seed_table(group, "best", protocol, "euler")
    slips = known_slips(table.published_label, table.evaluated)
    if not slips:
        return None
    return (
        f"- The published values ({table.published_label}) of {', '.join(slips)} are slips of "
        "the paper (shared docs/published_results.md): "
        + "; ".join(slips.values())
        + ". They are kept as printed, so the published averages that include them are off too."
    )


def missed_targets(groups: list[Group], protocol: str, targets: dict) -> list[str]:
    """Labels of the groups whose best or last checkpoint misses its dataset's target."""
    missed = []
    for group in groups:
        target = targets.get(group.dataset)
        if target is None:
            continue
        for selection in SELECTIONS:
            table = seed_table(group, selection, protocol, "euler")
            average = _mean_average(table)
            if average and _beyond(average, table.published_same_set(), target):
                missed.append(group.label)
                break
    return missed


def provenance_table(groups: list[Group], baselines: list[dict]) -> str:
    lines = [
        "| experiment | seed | run folder | commit | iterations | best at | wall time | device "
        "| data archive (sha256) | missing files | notes |",
        "|---|---:|---|---|---:|---:|---:|---|---|---|---|",
    ]
    for group in groups:
        for r in group.runs:
            missing = r.get("missing_files") or []
            wall = r.get("wall_time_s")
            lines.append(
                f"| {group.label} | {r['seed']} | `{r['path']}` | {r.get('commit') or '-'} | "
                f"{_range([r['iterations']])} | {_range([r['iterations_of']['best']])} | "
                f"{'-' if wall is None else f'{wall / 60:.1f} min'} | {r.get('device') or '-'} | "
                f"{r.get('archive_sha256', '-')} | "
                f"{f'{len(missing)} (see below)' if missing else 'none'} | "
                f"{'; '.join(r['notes']) or '-'} |"
            )
    for e in baselines:
        missing = e.get("missing_files") or []
        missing_txt = f"{len(missing)} (see below)" if missing else "none"
        lines.append(
            f"| {e['label']} ({e.get('kind', 'baseline')}) | - | - | {e.get('commit', '-')} | - "
            "| - | - | - | "
            f"{e.get('archive_sha256', '-')} | {missing_txt} | - |"
        )
    return "\n".join(lines)


def intro(groups: list[Group], protocols: list[str]) -> list[str]:
    seeds = "; ".join(
        f"{g.label} ({g.dataset}): {len(g.runs)} seed{'s' if len(g.runs) != 1 else ''} "
        f"({', '.join(str(r['seed']) for r in g.runs)})"
        for g in groups
    )
    return [
        f"**Seeds.** {seeds or 'no training runs'}. Every cell of a trained model is the mean "
        "± the sample standard deviation (n - 1 denominator) over its seeds, n as listed; a "
        "cell without ± comes from one seed. The average row's ± is that of the per-seed "
        "averages.",
        "",
        "**Checkpoint selection.** Each run is reported twice. *best (test-selected)*: the "
        "checkpoint with the lowest average Euler error at a validation during training; the "
        "validation windows are the test windows (S5 on H3.6M, the test folder on CMU), as in "
        "both reference implementations and as the papers report (protocol section 8), so this "
        "selection uses test information and is optimistic. *last (no test info)*: the "
        "checkpoint of the final iteration, chosen without looking at the test windows. Both are "
        "evaluated on every protocol below; the selection itself was made on the runs' "
        "validation protocol (8 windows per action unless a run's config says otherwise).",
        "",
        "**Published values.** Beside our average over the evaluated actions stands the "
        "paper's average recomputed from its per-action values over the same actions ('same N "
        "actions': like for like when this data copy lacks some test actions), and the average "
        "as printed in the paper, over all of its actions. Tables 5 and 6 of Li et al. (the "
        "ablations) print averages only, so they have no same-set value.",
    ]


def build_page(
    groups: list[Group],
    baselines: list[dict],
    protocols: list[str],
    command: str,
    budget: str | None,
    commit: str | None = None,
    targets: dict[str, float] | None = None,
    notes: dict[str, str] | None = None,
) -> str:
    targets = TARGETS if targets is None else targets
    notes = notes or {}
    lines = [
        "# Results",
        "",
        f"Generated by `python -m src.report` on {dt.date.today()} at commit "
        f"{commit or git_commit()}; "
        "every number below was computed by that command from the listed runs' checkpoints and "
        "from the baselines. Do not edit by hand: re-run the command.",
        "",
        f"Command: `{command}`",
        "",
    ]
    if budget:
        lines += [f"**Budget.** {budget}", ""]
    lines += intro(groups, protocols) + [""]
    lines += target_paragraph(groups, protocols[0], targets, notes)
    lines += ["## Provenance", "", provenance_table(groups, baselines), ""]
    everyone = [r for g in groups for r in g.runs] + baselines
    missing = sorted({m for e in everyone for m in e.get("missing_files") or []})
    if missing:
        lines += [
            f"The data copy lacks {len(missing)} file(s) of the full archives; training used what "
            "exists (`data.allow_partial=true`) and actions without test files are shown as "
            "absent: " + ", ".join(f"`{m}`" for m in missing),
            "",
        ]
    for protocol in protocols:
        lines += [
            f"## Average over the evaluated actions: {PROTOCOLS.get(protocol, protocol)}",
            "",
            "Euler-angle error (radians):",
            "",
            summary_table(groups, baselines, "euler", protocol),
            "",
            "MPJPE (mm on H3.6M, skeleton units on CMU):",
            "",
            summary_table(groups, baselines, "mpjpe", protocol),
            "",
        ]
    compared = comparison_lines(groups, protocols[0])
    if compared:
        lines += [
            f"## Settings compared ({PROTOCOLS.get(protocols[0], protocols[0])})",
            "",
            "Runs of one experiment that differ in one setting: the average Euler error over the "
            "evaluated actions (mean over seeds), the later row minus the first; negative means "
            "the later setting has the lower error. With one seed a side, compare a difference "
            "with the spread between seeds of the rows that have several.",
            "",
            *compared,
            "",
        ]
    lines += ["## Per-experiment tables", ""]
    for group in groups:
        lines += [f"### {group.label} ({group.dataset})", ""]
        folders = ", ".join(f"seed {r['seed']}: `{r['path']}`" for r in group.runs)
        lines += [
            f"- Runs: {folders}.",
            "- Best checkpoints at iteration(s) "
            + ", ".join(_range([r["iterations_of"]["best"]]) for r in group.runs)
            + f" of {_range([r['iterations'] for r in group.runs])}.",
        ]
        for selection in SELECTIONS:
            lines += gap_lines(group, selection, protocols[0], targets.get(group.dataset))
        for line in (training_data_line(group, protocols[0]), slip_line(group, protocols[0])):
            if line:
                lines.append(line)
        if group.label in notes:
            lines.append(f"- Note: {notes[group.label]}")
        lines.append("")
        for protocol in protocols:
            for metric in ("euler", "mpjpe"):
                for selection in SELECTIONS:
                    lines += [seed_table(group, selection, protocol, metric).to_markdown(), ""]
    for entry in baselines:
        for protocol in protocols:
            lines += [
                f"### {entry['label']} ({entry['dataset']}), {PROTOCOLS.get(protocol, protocol)}",
                "",
            ]
            for table_dict in entry["results"][protocol]["tables"]:
                published = _published_of(table_dict, entry["dataset"])
                table = table_from_dict(table_dict, published, table_dict.get("published_label"))
                lines += [table.to_markdown(), ""]
    return "\n".join(lines)


def target_paragraph(
    groups: list[Group], protocol: str, targets: dict[str, float], notes: dict[str, str]
) -> list[str]:
    """The reproduction target, which rows miss it, and the notes saying why."""
    checked = [g for g in groups if g.dataset in targets]
    if not checked:
        return []
    missed = missed_targets(checked, protocol, targets)
    goal = ", ".join(f"{d} {t:.2f}" for d, t in targets.items())
    text = (
        "**Reproduction target.** A trained row reproduces its paper when its average is within "
        f"the target of the published same-set average at every published horizon ({goal} "
        f"radians; {PROTOCOLS.get(protocol, protocol)}), for both checkpoints. "
    )
    # Rows whose paper prints an average only (Li et al.'s Tables 5 and 6) have no same-set
    # value, so missed_targets finds nothing to miss: they are not judged, not met.
    unjudged = []
    for group in checked:
        table = seed_table(group, "best", protocol, "euler")
        if table.published is not None and not table.published_same_set():
            unjudged.append(group.label)
    if unjudged:
        text += (
            "Not judged (their paper prints an average only, over all of its actions, so there "
            f"is no same-set value): {', '.join(unjudged)}. "
        )
    if not missed:
        text += "Every trained row with a published same-set average meets it."
        return [text, ""]
    text += "Rows that miss it: " + "; ".join(
        f"{label} ({notes.get(label, 'no explanation given')})" for label in missed
    )
    return [text + ".", ""]


def readme_block(
    groups: list[Group],
    baselines: list[dict],
    protocol: str,
    budget: str | None,
    commit: str | None = None,
    targets: dict[str, float] | None = None,
    notes: dict[str, str] | None = None,
) -> str:
    targets = TARGETS if targets is None else targets
    verdict = target_paragraph(groups, protocol, targets, notes or {})
    return "\n".join(
        [
            f"Average Euler-angle error over the evaluated actions, "
            f"{PROTOCOLS.get(protocol, protocol)}; generated on {dt.date.today()} at commit "
            f"{commit or git_commit()}. Trained models: mean ± std over seeds (n in the table), "
            "with the best checkpoint (selected on the test windows, as the papers did) and the "
            "last (no test information); published averages recomputed over the same actions and "
            "as printed." + (f" Budget: {budget}" if budget else ""),
            "",
            summary_table(groups, baselines, "euler", protocol),
        ]
        + ([""] + verdict[:1] if verdict else [])
    )


def replace_block(path: Path, name: str, text: str) -> None:
    """Replace what lies between `<!-- name:start -->` and `<!-- name:end -->` in `path`."""
    content = path.read_text()
    start, end = f"<!-- {name}:start -->", f"<!-- {name}:end -->"
    if start not in content or end not in content:
        raise SystemExit(f"error: {path} has no {start} ... {end} markers")
    head, rest = content.split(start, 1)
    _, tail = rest.split(end, 1)
    path.write_text(f"{head}{start}\n{text}\n{end}{tail}")


def parse_notes(items: list[str], labels: list[str]) -> dict[str, str]:
    """{label: text} from `--note LABEL=TEXT` items; a label may itself hold '=' (a group told
    apart by a setting, "martinez2017_res_sup (data.future_len=10)"), so the longest label that
    the item starts with wins."""
    notes = {}
    for item in items:
        matches = [label for label in labels if item.startswith(f"{label}=")]
        if not matches:
            raise SystemExit(
                f"error: --note {item!r}: expected EXPERIMENT=TEXT with EXPERIMENT one of the "
                f"runs' experiments: {', '.join(labels)}"
            )
        label = max(matches, key=len)
        text = item[len(label) + 1 :].strip()
        if not text:
            raise SystemExit(f"error: --note {item!r}: the text after '=' is empty")
        notes[label] = text
    return notes


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "runs",
        nargs="*",
        type=Path,
        help="run folders, or folders holding them (a multirun folder)",
    )
    parser.add_argument("--out", type=Path, default=PROJECT_ROOT / "docs" / "results.md")
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
    # Read before anything is written: the page and README block change the tree.
    commit = git_commit()

    stamp = dt.datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    work = (args.work_dir or PROJECT_ROOT / "outputs" / "report" / stamp).resolve()
    archives = Path(os.environ["MOTION_ARCHIVES"]) if os.environ.get("MOTION_ARCHIVES") else None

    runs = [load_run(path) for path in discover_runs(args.runs)]
    groups = group_runs(runs)  # from the configs alone: a bad --note fails before evaluating
    notes = parse_notes(args.note, [g.label for g in groups])
    scored = scored_entries(args.scored, args.protocols)  # read before anything is evaluated
    for index, run in enumerate(runs):
        evaluate_run(run, index, args.protocols, work)
        first = run["results"]["best"][args.protocols[0]]
        run["missing_files"] = first["provenance"]["missing_files"]

    datasets = sorted({g.dataset for g in groups})
    baselines: list[dict] = []
    if args.datasets is not None:
        datasets = [d for d in args.datasets if d != "none"]
    for dataset in datasets:
        for model in BASELINES:
            entry = {"label": model, "dataset": dataset, "commit": commit, "results": {}}
            for protocol in args.protocols:
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
    baselines += scored

    hashes: dict[str, str] = {}
    for entry in [r for g in groups for r in g.runs] + baselines:
        dataset = entry["dataset"] if "dataset" in entry else entry["config"]["data"]["name"]
        name = ARCHIVES.get(dataset)
        if archives is not None and name and (archives / name).exists():
            if name not in hashes:
                hashes[name] = f"{name} {sha256(archives / name)[:16]}…"
            entry["archive_sha256"] = hashes[name]

    command = shlex.join(["python", "-m", "src.report", *(sys.argv[1:] if argv is None else argv)])
    page = build_page(
        groups, baselines, args.protocols, command, args.budget, commit, targets, notes
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(page)
    if args.readme is not None:
        replace_block(
            args.readme,
            "results",
            readme_block(groups, baselines, args.protocols[0], args.budget, commit, targets, notes),
        )
    work.mkdir(parents=True, exist_ok=True)
    raw = {
        "groups": [
            {"label": g.label, "run_name": g.run_name, "dataset": g.dataset, "runs": g.runs}
            for g in groups
        ],
        "baselines": baselines,
    }
    (work / "report.json").write_text(json.dumps(raw, indent=1, default=str))
    print(f"wrote {args.out} (raw results in {work})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
