"""Error-versus-horizon plot of several evaluations (Li et al. 2018, Figure 4, on our runs).

    python -m src.plot_errors results=[runs/a/t/results.json,runs/b/t/results.json]
    python -m src.plot_errors results=[...] metric=mpjpe action=walking out=walking_mpjpe.png

One line per results.json of `python -m src.eval`, for the average row (mean over the evaluated
actions, protocol §4.1 step 6) or one action; `published=true` adds the paper's curve, dashed,
where the results carry one. The image goes into the command's own run folder unless `out=`
names a new file: nothing is written over. Each line is labelled by its run's name and dataset,
told apart further where two would read the same; the files must share one dataset.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib
from matplotlib.backend_bases import FigureCanvasBase
from omegaconf import DictConfig, OmegaConf

from src.cli import hydra_entry
from src.lit.factory import ConfigError
from src.lit.run_folders import nothing_left_if_refused
from src.plots import error_vs_horizon
from src.reporting.published import published_datasets
from src.reporting.tables import read_results

METRICS = {"euler": "Euler-angle error (rad)", "mpjpe": "MPJPE"}


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


@hydra_entry("plot_errors")
def main(cfg: DictConfig) -> Path:
    matplotlib.use("Agg")
    paths = cfg.results if OmegaConf.is_list(cfg.results) else [cfg.results]
    if not paths or paths == [None]:
        raise ConfigError("say which runs to plot: results=[path/to/results.json,...]")
    if not isinstance(cfg.published, bool):
        raise ConfigError(f"published={cfg.published!r}: write true or false")
    labels = None if cfg.labels is None else [str(x) for x in cfg.labels]
    out = cfg.out or Path(cfg.paths.output_dir) / f"errors_{cfg.metric}_{cfg.action}.png"
    with nothing_left_if_refused(None):
        written = plot_errors(
            [str(p) for p in paths], out, cfg.metric, cfg.action, labels, cfg.published
        )
    print(f"written to {written}")
    return written


if __name__ == "__main__":
    main()
