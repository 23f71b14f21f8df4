"""Error-versus-horizon plot of several evaluations (Li et al. 2018, Figure 4, on our runs).

    python -m src.plot_errors results=[runs/a/t/results.json,runs/b/t/results.json]
    python -m src.plot_errors results=[...] metric=mpjpe action=walking out=walking_mpjpe.png
    python -m src.plot_errors results=[...] labels=[ours,zero-velocity] published=true

Reads the results.json files written by `python -m src.eval` and draws one line per file for
the average row (mean over the evaluated actions, protocol §4.1 step 6) or one action.
`published=true` adds the paper's curve, dashed, where results.json carries one.
Arguments are `key=value` pairs (OmegaConf's command-line syntax); `out` defaults to
outputs/plots/errors_<metric>_<action>.png.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import matplotlib
from omegaconf import OmegaConf

from src.lit.factory import PROJECT_ROOT, ConfigError
from src.lit.validation import friendly_errors
from src.reporting.plots import error_vs_horizon

METRICS = {"euler": "Euler-angle error (rad)", "mpjpe": "MPJPE"}


def read_results(path: str | Path) -> dict:
    """The parsed results.json of one `python -m src.eval` run."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(
            f"results file not found: {path}. `python -m src.eval ...` writes results.json "
            "into its run folder under outputs/eval/runs/."
        )
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise ConfigError(f"{path} is not valid JSON: {err}") from err
    if not isinstance(data, dict) or "tables" not in data:
        raise ConfigError(f"{path} has no 'tables'; is it a results.json from src.eval?")
    return data


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
    curves, dashed, units = [], [], set()
    for i, path in enumerate(paths):
        data = read_results(path)
        ours, pub, unit = curve(data, metric, action, str(path))
        units.add(unit)
        prov = data.get("provenance", {})
        label = labels[i] if labels else f"{prov.get('model', Path(path).parent.name)}"
        curves.append((label, ours))
        if published and pub:
            ref = next(t for t in data["tables"] if t["metric"] == metric)["published_label"]
            name = f"{ref or 'published'} (paper)"
            if name not in dashed:
                curves.append((name, pub))
                dashed.append(name)
    unit = "/".join(sorted(units))
    datasets = sorted({read_results(p).get("provenance", {}).get("dataset", "?") for p in paths})
    fig = error_vs_horizon(
        curves,
        title=f"{action} on {', '.join(datasets)}",
        ylabel=f"{METRICS[metric]} ({unit})" if metric == "mpjpe" else METRICS[metric],
        dashed=dashed,
    )
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    return out


@friendly_errors
def main(argv: list[str] | None = None) -> Path:
    matplotlib.use("Agg")
    args = OmegaConf.from_dotlist(sys.argv[1:] if argv is None else argv)
    unknown = set(args) - {"results", "out", "metric", "action", "labels", "published"}
    if unknown:
        raise ConfigError(f"unknown argument(s) {sorted(unknown)}; see `python -m src.plot_errors`")
    results = args.get("results")
    if results is None:
        raise ConfigError("say which runs to plot: results=[path/to/results.json,...]")
    paths = [str(p) for p in (results if OmegaConf.is_list(results) else [results])]
    metric, action = args.get("metric", "euler"), args.get("action", "average")
    out = args.get("out") or PROJECT_ROOT / "outputs" / "plots" / f"errors_{metric}_{action}.png"
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
