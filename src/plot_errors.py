"""Error against horizon of several evaluations (Li et al. 2018, Figure 4, on our runs):

    python -m src.plot_errors results=[a/results.json,b/results.json] action=walking

A line per results.json of src.eval (one dataset), `published=true` adds the paper's, dashed;
into the command's own run folder unless `out=` names a new file."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from matplotlib.backend_bases import FigureCanvasBase
from omegaconf import DictConfig, OmegaConf

from src.cli import hydra_entry
from src.config import ConfigError
from src.plots import error_vs_horizon
from src.reporting.published import published_datasets
from src.reporting.tables import read_results

METRICS = {"euler": "Euler-angle error (rad)", "mpjpe": "MPJPE"}


def curve(results: dict, metric: str, action: str, source: str) -> tuple[dict, dict | None, dict]:
    """({ms: ours}, {ms: published} or None, the table) of one metric and action."""
    if not (tables := [t for t in results["tables"] if t["metric"] == metric]):
        found = [t["metric"] for t in results["tables"]]
        raise ConfigError(f"{source}: no {metric!r} table (has {found}); use metric=euler|mpjpe")
    table = tables[0]
    if action == "average" and table["average"] is None:
        raise ConfigError(f"{source}: no action was evaluated, so there is no average")
    if action in table["absent"]:
        raise ConfigError(f"{source}: {action} is absent there ({table['absent'][action]})")
    if action != "average" and action not in table["values"]:
        raise ConfigError(f"{source}: unknown action {action!r}; actions: {table['actions']}")
    values = table["average"]["values"] if action == "average" else table["values"][action]
    published = (table.get("published") or {}).get(action)
    as_ms = lambda row: {int(k): float(v) for k, v in row.items()}  # noqa: E731
    return as_ms(values), as_ms(published) if published else None, table


def plot_errors(paths, out, metric="euler", action="average", labels=None, published=False):
    if metric not in METRICS:
        raise ConfigError(f"metric={metric!r}: choose one of {', '.join(METRICS)}")
    if labels is not None and len(labels) != len(paths):
        raise ConfigError(f"labels has {len(labels)} entries for {len(paths)} results files")
    # A plot is the user's: never written over. savefig would replace a file, add .png to a
    # name without an extension (printed without it) and fail on an unknown one.
    out, formats = Path(out), FigureCanvasBase.get_supported_filetypes()
    if out.suffix.lstrip(".").lower() not in formats:
        raise ConfigError(f"out={out} has no image extension matplotlib writes; end it in .png")
    if out.exists():
        raise ConfigError(f"out={out} already exists; nothing was overwritten. Give another out=.")
    results = [read_results(path) for path in paths]
    found = [r.get("provenance", {}).get("dataset") or "?" for r in results]
    if len(datasets := sorted(set(found) - {"?"}) or ["?"]) > 1:
        each = ", ".join(f"{Path(p)}: {d}" for p, d in zip(paths, found, strict=True))
        raise ConfigError(
            f"the results come from different datasets ({', '.join(datasets)}), whose errors are "
            f"not comparable on one plot ({each}). Plot each dataset on its own."
        )
    names = legend_labels(results, paths) if labels is None else list(labels)
    if twice := sorted(n for n, k in Counter(names).items() if k > 1):
        raise ConfigError(f"labels name {twice} more than once; give each results file its own")
    curves, dashed, units = [], [], set()
    for name, data, path in zip(names, results, paths, strict=True):
        ours, pub, table = curve(data, metric, action, str(path))
        units.add(table["unit"])
        curves.append((name, ours))
        paper = f"{table.get('published_label') or 'published'} (paper)"
        if published and pub and datasets[0] in published_datasets() and paper not in dashed:
            curves.append((paper, pub))
            dashed.append(paper)
    unit = f" ({'/'.join(sorted(units))})" if metric == "mpjpe" else ""  # euler's says rad
    out.parent.mkdir(parents=True, exist_ok=True)
    title = f"{action} on {', '.join(datasets)}"
    error_vs_horizon(curves, title=title, ylabel=METRICS[metric] + unit, dashed=dashed).savefig(out)
    return out


def legend_labels(results: list[dict], paths: list) -> list[str]:
    """ "<run name> (<dataset>)" per file, and where two read the same, what tells them apart
    (protocol, checkpoint, folder), else a number."""
    provs = [r.get("provenance", {}) for r in results]
    run = lambda p, path: p.get("run_name") or p.get("model") or Path(path).parent.name  # noqa: E731
    labels = [f"{run(p, x)} ({p.get('dataset') or '?'})" for p, x in zip(provs, paths, strict=True)]
    for extra in (
        lambda p, path: p.get("eval_protocol"),
        lambda p, path: Path(p["checkpoint"]).name if p.get("checkpoint") else None,
        lambda p, path: Path(path).parent.name,
    ):
        values = [extra(p, path) for p, path in zip(provs, paths, strict=True)]
        alike = [{values[j] for j, y in enumerate(labels) if y == x} for x in labels]
        labels = [
            f"{x}, {v}" if v and len(same) > 1 else x
            for x, v, same in zip(labels, values, alike, strict=True)
        ]
    counts, seen = Counter(labels), Counter()
    for k, label in enumerate(labels):
        seen[label] += 1
        labels[k] = label if counts[label] == 1 else f"{label} #{seen[label]}"
    return labels


@hydra_entry("plot_errors")
def main(cfg: DictConfig) -> Path:
    paths = cfg.results if OmegaConf.is_list(cfg.results) else [cfg.results]
    if not paths or paths == [None]:
        raise ConfigError("say which runs to plot: results=[path/to/results.json,...]")
    if not isinstance(cfg.published, bool):
        raise ConfigError(f"published={cfg.published!r}: write true or false")
    labels = None if cfg.labels is None else [str(x) for x in cfg.labels]
    out = cfg.out or Path(cfg.paths.output_dir) / f"errors_{cfg.metric}_{cfg.action}.png"
    out = plot_errors([str(p) for p in paths], out, cfg.metric, cfg.action, labels, cfg.published)
    print(f"written to {out}")
    return out


if __name__ == "__main__":
    main()
