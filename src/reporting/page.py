"""The results page (docs/results.md), its per-action CSVs and figures, and the README's block:
the headline (headline.py), budget, data copy and slips, ablation claims (claims.py), provenance,
the averages of each protocol and metric, the CSVs, the command. The numbers are frame.py's."""

from __future__ import annotations

import datetime as dt
import itertools
import os
from pathlib import Path

import pandas as pd

import src.reporting.frame as fr
import src.reporting.headline as hl
from src.config import ConfigError
from src.reporting.claims import claims_section
from src.reporting.frame import HORIZONS, PROTOCOLS, SELECTION_LABELS, SELECTIONS, Results
from src.reporting.published import published_frame
from src.reporting.tables import AVERAGE, fmt, markdown


def replace_block(path: Path, name: str, text: str | None = None) -> None:
    """Put `text` between `path`'s `<!-- name:start -->` and `<!-- name:end -->` (None: check)."""
    start, end = f"<!-- {name}:start -->", f"<!-- {name}:end -->"
    content = Path(path).read_text() if Path(path).is_file() else ""
    if start not in content or end not in content.split(start, 1)[-1]:
        raise ConfigError(f"readme={path} has no {start} ... {end} markers to write between")
    if text is not None:
        head, rest = content.split(start, 1)
        Path(path).write_text(f"{head}{start}\n{text}\n{end}{rest.split(end, 1)[1]}")


def _wall_time(run: dict) -> str:
    """Over all segments; of a run resumed before src.train kept the total, the last one's."""
    if (total := run.get("train_time_s")) is not None:
        return f"{total / 60:.1f} min"
    if (wall := run.get("wall_time_s")) is None:
        return "-"
    return f"{wall / 60:.1f} min" + (" (last segment)" if run["config"].get("ckpt_path") else "")


def provenance_table(results: Results) -> str:
    rows = []
    for group in results.entries:
        for r in group.runs:
            missing, commit = len(r.get("missing_files") or []), r.get("commit") or "-"
            row = [f"{group.label} ({group.kind})", "-", "-", commit, "-", "-", "-"]
            if group.kind == "trained":
                row[:3] = group.label, str(r["seed"]), f"`{r['path']}`"
                row[4:] = (
                    f"{r.get('iterations') or group.iterations:,}",  # this seed's own
                    hl.span([r["iterations_of"]["best"]]),
                    _wall_time(r),
                )
            row += [r.get("device") or "-", r.get("archive_sha256", "-")]
            row += [str(missing or "none")]
            rows.append([*row, "; ".join(r.get("notes", [])) or "-"])
    columns = ["experiment", "seed", "run folder", "commit", "iterations", "best at"]
    columns += ["wall time", "device", "data archive (sha256)", "missing files", "notes"]
    return markdown(rows, columns)


def averages_table(results: Results, protocol: str, metric: str, published: bool) -> str:
    """Each group's averages, best and last; `published`: each reference's, same-set and printed."""
    decimals, rows = (2 if metric == "euler" else 1), []
    for group in results.entries:
        trained, last = group.kind == "trained", f"{group.iterations:,}"
        best = f"{hl.span(r.get('iterations_of', {}).get('best') for r in group.runs)} of {last}"
        for s in SELECTIONS if trained else ("-",):
            n, budget = str(len(group.runs)), best if s == "best" else last
            row = [group.label, group.dataset, SELECTION_LABELS.get(s, "-")]
            row += [n, budget] if trained else ["-", "-"]
            rows.append(row + hl.stat_cells(results.average(group, protocol, s, metric), decimals))
        evaluated = results.actions(group, judged=False)
        for ref in results.refs[group] if published and metric == "euler" else ():
            slips = results.slips_in(ref, evaluated)
            flag = f" (slips of the paper left out: {', '.join(slips)})" if slips else ""
            n = len(set(ref.published) - {AVERAGE})
            same = results.same_set(group, ref, judged=False)
            printed = ref.published.get(AVERAGE, {})
            for what, values in (
                (f"same {len(evaluated) - len(slips)} actions{flag}", same),
                (f"as printed (all {n or 'of its'} actions)", printed),
            ):
                label = f"{group.label}: published ({ref.key}), {what}"
                cells = [fmt(values.get(ms)) for ms in HORIZONS]
                rows += [[label, group.dataset, "paper", "-", "paper", *cells]] if values else []
    return markdown(rows, ["experiment", "dataset", "checkpoint", "n", "iterations", *hl.COLS])


def per_action_csv(results: Results, protocol: str, metric: str) -> str:
    """Each group's per-action mean, std (n - 1) and published value; why an action is absent."""
    f = results.frame[(results.frame.protocol == protocol) & (results.frame.metric == metric)]
    keys = ["g", "checkpoint", "action"]
    rows = f.groupby(keys, sort=False)
    out = rows.seed.nunique().rename("n").to_frame()
    out["note"] = rows.absent.first().where(
        rows.absent.first().astype(bool) | rows.trained.first(), "no training files in this copy"
    )
    stats = f.groupby([*keys, "horizon"]).value.agg(["mean", "std"]).unstack("horizon")
    for ms in (ms for ms in HORIZONS if ms in stats.columns.get_level_values("horizon")):
        out[f"{ms} ms"], out[f"{ms} ms std"] = stats["mean", ms], stats["std", ms]
    out = out.reset_index()
    first = {g: r[0].published for g, e in enumerate(results.entries) if (r := results.refs[e])}
    for ms in HORIZONS if metric == "euler" else ():
        pairs = zip(out.g, out.action, strict=True)
        out[f"{ms} ms published"] = [first.get(g, {}).get(a, {}).get(ms) for g, a in pairs]
    groups = [results.entries[g] for g in out.pop("g")]
    out.insert(0, "iterations", [g.iterations if g.kind == "trained" else "" for g in groups])
    out.insert(0, "data", [g.dataset for g in groups])
    out.insert(0, "experiment", [g.label for g in groups])
    return out.to_csv(index=False)


def reading(results: Results) -> list[str]:
    """The runs of one seed counted once (groups.py); the headline's legend says the rest."""
    left_out = [line for g in results.groups for line in g.left_out]
    return ["**Runs counted once.** " + "; ".join(left_out) + ".", ""] if left_out else []


def data_lines(results: Results) -> list[str]:
    """What this data copy lacks, counted, and the published values that are slips of the papers."""
    everyone = [r for g in results.entries for r in g.runs]
    missing = {m for r in everyone for m in r.get("missing_files") or []}
    short, slips, lines = {}, {}, []
    for group in hl.headline_groups(results):
        evaluated, files = results.actions(group, judged=False), results.files[group].items()
        if lack := [f"{a} {p} of {n}" for a, (p, n) in files if p < n and a in evaluated]:
            short.setdefault(group.dataset, lack)
        for ref in results.refs[group]:
            slips.setdefault(ref.key, {}).update(results.slips_in(ref, evaluated))
    if missing:  # the list itself would be 30 lines of this page: counted, and where it is
        lines.append(
            f"It lacks {len(missing)} file(s) of the full archives (the records' missing_files "
            "list them, as `hydra.verbose=src.data.base` does on any command); actions without "
            "test files are absent."
        )
    if short := "; ".join(f"{d} {', '.join(s)}" for d, s in short.items()):
        lines.append(f"Training files present of the evaluated actions: {short}.")
    lines = [" ".join(["**Data copy.**", *lines])] if lines else []
    cells = results.slip_cells.groupby(["key", "action"], sort=False).ms.agg(list)
    said = [f"{k}: {', '.join(a)}" for k, a in slips.items() if a]
    if len(cells):  # zero-velocity is deterministic: a cell beyond rounding is the paper's slip
        found = ", ".join(f"{a} ({fr.ms_list(ms)})" for (_, a), ms in cells.items())
        keys = ", ".join(cells.index.unique(0))
        said.append(f"{keys}, published more than {fr.ROUNDING} from ours: {found}")
    if said:
        lines.append(
            "**Slips of the papers**, left out of the same-set averages on both sides (each "
            "cell and why in [published.csv](results/published.csv)): " + "; ".join(said) + "."
        )
    return [x for line in lines for x in (line, "")]


def published_csv(results: Results) -> str:
    """Every published cell of the references on the page, zero-velocity's beside it as the
    protocol gives it on this data, and why it is a slip: found by the protocol, else its
    action's known slip (references.json); '' if not."""
    keys = {r.key for e in results.entries for r in results.refs[e]}
    f = published_frame().assign(key=lambda f: f.paper + " " + f.method)
    zero = results.zero_cells.assign(found=lambda z: z.why.where(z.slip))
    on = ["key", "dataset", "action", "ms"]
    f = f[f.key.isin(keys)].merge(zero[[*on, "ours", "found"]], how="left", on=on)
    known = [results.slips.get(k, {}).get(a, "") for k, a in zip(f.key, f.action, strict=True)]
    f["slip"] = f.pop("found").astype(object).fillna(pd.Series(known, dtype=object))
    return f.drop(columns="key").to_csv(index=False, float_format="%.4g")


def build_page(
    results, protocols, command, budget, commit, targets, notes=None, figures=(), tables=None
) -> str:
    """The page; `figures`: the figures' file names, `tables`: the CSVs' folder, beside it."""
    first, where = protocols[0], PROTOCOLS.get(protocols[0], protocols[0])
    intro = (
        f"Generated by `python -m src.report` on {dt.date.today()} at commit {commit} from the "
        "runs under Provenance (the command is at the end); do not edit by hand. Average "
        f"Euler-angle error (radians) over the evaluated actions, {where}."
    )
    head = hl.headline(results, first, targets, figures, "#ablations", intro, notes or {})
    lines = ["# Results", "", *head]
    lines += [f"**Budget.** {budget}", ""] if budget else []
    lines += reading(results) + data_lines(results)
    lines += claims_section(results, protocols, "Ablations")
    folders = "Run folders are relative to the folder that holds them all (the project's)."
    lines += ["## Provenance", "", provenance_table(results), "", folders, ""]
    for metric, what in (("euler", "Euler-angle error (radians)"), ("mpjpe", "MPJPE")):
        for k, protocol in enumerate(protocols):
            table = averages_table(results, protocol, metric, published=k == 0)
            lines += [f"## Averages: {what}, {PROTOCOLS.get(protocol, protocol)}", "", table, ""]
    if tables:
        links = [f"[{m} {p}]({tables}/{m}_{p}.csv)" for m in ("euler", "mpjpe") for p in protocols]
        what = "mean, std over the seeds, published, notes; MPJPE in mm on H3.6M, skeleton units "
        what += "on CMU"
        lines += ["## Per-action tables", "", f"As CSV ({what}): {', '.join(links)}.", ""]
    return "\n".join([*lines, "## Command", "", f"`{command}`", ""])


def write_page(results, out: Path, protocols, command, budget, commit, targets, notes, readme):
    """The page, <stem>_{errors,validation}.png, <stem>/<metric>_<protocol>.csv, the README's."""
    tables = out.with_suffix("")
    tables.mkdir(parents=True, exist_ok=True)
    for m, p in itertools.product(("euler", "mpjpe"), protocols):
        (tables / f"{m}_{p}.csv").write_text(per_action_csv(results, p, m))
    (tables / "published.csv").write_text(published_csv(results))
    figures, names = hl.figures(results, protocols[0]), [None, None]
    for k, (figure, kind) in enumerate(zip(figures, ("errors", "validation"), strict=True)):
        if figure is not None:
            names[k] = f"{out.stem}_{kind}.png"
            figure.savefig(out.with_name(names[k]))
    page = (results, protocols, command, budget, commit, targets, notes, names, tables.name)
    out.write_text(build_page(*page))
    if readme:
        here = readme.resolve().parent
        figure = os.path.relpath(out.with_name(names[0]), here) if names[0] else None
        page = os.path.relpath(out, here)
        block = hl.readme_block(results, protocols[0], commit, targets, figure, page)
        replace_block(readme, "results", block)
