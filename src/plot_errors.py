"""Error-versus-horizon plot of several evaluations (Li et al. 2018, Figure 4, on our runs).

    python -m src.plot_errors results=[runs/a/t/results.json,runs/b/t/results.json]
    python -m src.plot_errors results=[...] metric=mpjpe action=walking out=walking_mpjpe.png
    python -m src.plot_errors results=[...] labels=[ours,zero-velocity] published=true

Reads the results.json files written by `python -m src.eval` and draws one line per file for
the average row (mean over the evaluated actions, protocol §4.1 step 6) or one action.
`published=true` adds the paper's curve, dashed, where results.json carries one.
Arguments are `key=value` pairs (OmegaConf's command-line syntax); `out` defaults to
outputs/plots/errors_<metric>_<action>.png (-1, -2, ... when taken). No file is written over:
an `out` that exists is refused.

Each line is labelled by its run's name and dataset ("zero_velocity (cmu)"), told apart further
where two would read the same. All files must come from one dataset: errors on different
datasets are not comparable on one axis.
"""

from __future__ import annotations

import difflib
import sys
from pathlib import Path

import matplotlib
from matplotlib.backend_bases import FigureCanvasBase
from omegaconf import OmegaConf

from src.cli import friendly_errors
from src.lit.factory import PROJECT_ROOT, ConfigError
from src.reporting.plots import error_vs_horizon
from src.reporting.published import published_datasets
from src.results import read_results

METRICS = {"euler": "Euler-angle error (rad)", "mpjpe": "MPJPE"}
OPTIONS = {
    "results": "[a/results.json,b/results.json,...]  the results.json files of src.eval (required)",
    "metric": "euler|mpjpe  which error (default euler)",
    "action": "NAME|average  one action, or the mean over the evaluated actions (default)",
    "labels": "[name,...]  legend entries, one per results file (default: run name and dataset)",
    "published": "true|false  add the paper's curve, dashed, where the results carry one",
    "out": "PATH.png  a new file (default outputs/plots/errors_<metric>_<action>[-N].png)",
}


def usage() -> str:
    """What `python -m src.plot_errors --help` prints."""
    lines = [__doc__.strip(), "", "Arguments (key=value):"]
    lines += [f"  {key}={text}" for key, text in OPTIONS.items()]
    return "\n".join(lines)


def curve(
    results: dict, metric: str = "euler", action: str = "average", source: str = "results"
) -> tuple[dict[int, float], dict[int, float] | None, str]:
    """({ms: ours}, {ms: published} or None, unit) of one metric and action (or "average")."""
    tables = [t for t in results["tables"] if t["metric"] == metric]
    if not tables:
        found = [t["metric"] for t in results["tables"]]
        raise ConfigError(f"{source}: no {metric!r} table (has {found}); use metric=euler|mpjpe")
    table = tables[0]
    if action == "average":
        if table["average"] is None:
            raise ConfigError(f"{source}: no action was evaluated, so there is no average")
        values = table["average"]["values"]
    elif action in table["values"]:
        values = table["values"][action]
    elif action in table["absent"]:
        raise ConfigError(f"{source}: {action} is absent there ({table['absent'][action]})")
    else:
        raise ConfigError(f"{source}: unknown action {action!r}; actions: {table['actions']}")
    published = (table.get("published") or {}).get(action)
    as_ms = lambda row: {int(k): float(v) for k, v in row.items()}  # noqa: E731
    return as_ms(values), as_ms(published) if published else None, table["unit"]


def plot_errors(
    paths: list[str | Path],
    out: str | Path,
    metric: str = "euler",
    action: str = "average",
    labels: list[str] | None = None,
    published: bool = False,
) -> Path:
    """Write the error-versus-horizon PNG of the results.json files `paths`; return its path."""
    if metric not in METRICS:
        raise ConfigError(f"metric={metric!r}: choose one of {', '.join(METRICS)}")
    if not paths:
        raise ConfigError("results=[...] is empty: give at least one results.json")
    if labels is not None and len(labels) != len(paths):
        raise ConfigError(f"labels has {len(labels)} entries for {len(paths)} results files")
    out = Path(out)
    check_out(out)
    results = [read_results(path) for path in paths]
    datasets = one_dataset(results, paths)
    names = legend_labels(results, paths) if labels is None else list(labels)
    if len(set(names)) < len(names):
        twice = sorted({n for n in names if names.count(n) > 1})
        raise ConfigError(f"labels name {twice} more than once; give each results file its own")
    curves, dashed, units = [], [], set()
    for name, data, path in zip(names, results, paths, strict=True):
        ours, pub, unit = curve(data, metric, action, str(path))
        units.add(unit)
        curves.append((name, ours))
        if published and pub and datasets[0] in published_datasets():
            ref = next(t for t in data["tables"] if t["metric"] == metric)["published_label"]
            paper = f"{ref or 'published'} (paper)"
            if paper not in dashed:
                curves.append((paper, pub))
                dashed.append(paper)
    unit = "/".join(sorted(units))
    fig = error_vs_horizon(
        curves,
        title=f"{action} on {', '.join(datasets)}",
        ylabel=f"{METRICS[metric]} ({unit})" if metric == "mpjpe" else METRICS[metric],
        dashed=dashed,
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    return out


def check_out(out: Path) -> None:
    """A plot is the user's: never written over. savefig would replace an existing file, add
    .png to a name without an extension (printed without it) and fail on an unknown one."""
    formats = FigureCanvasBase.get_supported_filetypes()
    if out.suffix.lstrip(".").lower() not in formats:
        raise ConfigError(
            f"out={out} has no image extension matplotlib writes; end it in .png, .pdf or .svg "
            f"(or {', '.join(f'.{f}' for f in sorted(formats) if f not in ('png', 'pdf', 'svg'))})"
        )
    if out.exists():
        raise ConfigError(
            f"out={out} already exists; nothing was overwritten. Give another out=, or remove "
            "the file first."
        )


def free_path(path: Path) -> Path:
    """`path`, or `<stem>-1<suffix>`, `-2`, ... where that exists (the default out=)."""
    candidate, n = path, 0
    while candidate.exists():
        n += 1
        candidate = path.with_name(f"{path.stem}-{n}{path.suffix}")
    return candidate


def one_dataset(results: list[dict], paths: list) -> list[str]:
    """The dataset of the results files, which must be one: refuse a mix, naming each file's."""
    found = [r.get("provenance", {}).get("dataset") or "?" for r in results]
    known = sorted(set(found) - {"?"})
    if len(known) > 1:
        each = ", ".join(f"{Path(p)}: {d}" for p, d in zip(paths, found, strict=True))
        raise ConfigError(
            f"the results come from different datasets ({', '.join(known)}), whose errors are "
            f"not comparable on one plot ({each}). Plot each dataset on its own."
        )
    return known or ["?"]


def legend_labels(results: list[dict], paths: list) -> list[str]:
    """One legend entry per results file: "<run name> (<dataset>)", followed, where two would
    read the same, by what tells them apart (protocol, checkpoint, folder), else a number."""
    labels = []
    for data, path in zip(results, paths, strict=True):
        prov = data.get("provenance", {})
        run = prov.get("run_name") or prov.get("model") or Path(path).parent.name
        labels.append(f"{run} ({prov.get('dataset') or '?'})")
    for extra in (
        lambda prov, path: prov.get("eval_protocol"),
        lambda prov, path: Path(prov["checkpoint"]).name if prov.get("checkpoint") else None,
        lambda prov, path: Path(path).parent.name,
    ):
        labels = _tell_apart(labels, results, paths, extra)
    seen: dict[str, int] = {}
    unique = []
    for label in labels:
        seen[label] = seen.get(label, 0) + 1
        unique.append(label if labels.count(label) == 1 else f"{label} #{seen[label]}")
    return unique


def _tell_apart(labels: list[str], results: list[dict], paths: list, extra) -> list[str]:
    """Add `extra(provenance, path)` to the labels that coincide, where it differs among them."""
    out = list(labels)
    for label in set(labels):
        same = [i for i, x in enumerate(labels) if x == label]
        if len(same) < 2:
            continue
        values = [extra(results[i].get("provenance", {}), paths[i]) for i in same]
        if len(set(values)) > 1:
            for i, value in zip(same, values, strict=True):
                out[i] = f"{label}, {value}" if value else label
    return out


@friendly_errors
def main(argv: list[str] | None = None) -> Path | None:
    matplotlib.use("Agg")
    argv = sys.argv[1:] if argv is None else argv
    if any(a in ("-h", "--help", "help") for a in argv):
        print(usage())
        return None
    options = [a for a in argv if a.startswith("-")]
    if options:
        raise ConfigError(
            f"unknown option(s) {options}: arguments are key=value; `python -m src.plot_errors "
            "--help` lists them"
        )
    try:
        args = OmegaConf.from_dotlist(argv)
    except Exception as err:  # noqa: BLE001 (OmegaConf's grammar errors)
        raise ConfigError(
            f"cannot read the arguments {argv}: {' '.join(str(err).split())}. Write key=value, "
            "e.g. results=[a/results.json,b/results.json]"
        ) from None
    unknown = set(args) - set(OPTIONS)
    if unknown:
        close = {k: difflib.get_close_matches(str(k), list(OPTIONS), n=1) for k in unknown}
        hints = [f"{k} (did you mean {c[0]}?)" if c else str(k) for k, c in sorted(close.items())]
        raise ConfigError(
            f"unknown argument(s): {', '.join(hints)}. Arguments: {', '.join(OPTIONS)} "
            "(`python -m src.plot_errors --help`)"
        )
    results = args.get("results")
    if results is None:
        raise ConfigError("say which runs to plot: results=[path/to/results.json,...]")
    paths = [str(p) for p in (results if OmegaConf.is_list(results) else [results])]
    metric, action = args.get("metric", "euler"), args.get("action", "average")
    out = args.get("out") or free_path(
        PROJECT_ROOT / "outputs" / "plots" / f"errors_{metric}_{action}.png"
    )
    labels = args.get("labels")
    written = plot_errors(
        paths,
        out,
        metric,
        action,
        labels=[str(x) for x in labels] if labels is not None else None,
        published=bool(args.get("published", False)),
    )
    print(f"written to {written}")
    return written


if __name__ == "__main__":
    main()
