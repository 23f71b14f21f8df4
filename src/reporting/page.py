"""The results page (docs/results.md), its per-action CSVs and figures, and the README's block:
the headline (headline.py), budget, how to read it, ablation claims (claims.py), provenance, the
averages of each protocol and metric, the CSVs, the command. The numbers are frame.py's."""

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
            row += [f"{missing} (see above)" if missing else "none"]
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
    """How to read the page; each row's seeds are under Provenance."""
    lines = [
        "**Seeds.** A cell is the mean ± the sample standard deviation (n - 1) over the seeds' "
        "averages (each seed's under Provenance); without ±, one seed.",
        "",
    ]
    if left_out := [line for g in results.groups for line in g.left_out]:
        lines += ["**Runs counted once.** " + "; ".join(left_out) + ".", ""]
    return lines + [
        "**Checkpoints.** *best (test-selected)*: the lowest average Euler error at a validation "
        "during training, on the test windows, as both reference implementations and the papers "
        "(protocol section 8): this selection uses test information and is optimistic. *last (no "
        "test info)*: the final iteration, chosen without looking at the test windows. "
        "**Published values.** The paper's average recomputed from its per-action values over "
        "the actions evaluated here ('same N actions': like for like when this copy lacks some), "
        "and as printed, over all of its actions; Li et al.'s Tables 5 and 6 print averages only.",
        "",
    ]


def _validation_text(results: Results, group, protocol: str, judgement) -> str:
    """A missing row at each of its validations: is the miss one checkpoint's or the run's?"""
    if not (means := results.validation_means(group, protocol)):
        return ""
    # A validation averages every evaluated action, those without training files too, so the
    # published value beside it is the one over the same actions, not the judged set's.
    same, steps = results.same_set(group, judgement.reference, judged=False), list(means)
    when = f"iterations {steps[0]:,} to {steps[-1]:,}" if steps[1:] else f"iteration {steps[0]:,}"
    if len(gaps := {b - a for a, b in zip(steps, steps[1:], strict=False)}) == 1:
        when += f", every {gaps.pop():,}"
    if len(group.runs) > 1:
        when += f"; mean over {len(group.runs)} seeds"
    if untrained := results.untrained_actions(group):
        evaluated = results.actions(group, judged=False)
        when += f"; all {len(evaluated)} actions, {', '.join(untrained)} (no training files) too"
    horizons = sorted({ms for hs in judgement.missed.values() for ms in hs})
    at = [
        " ".join(fmt(means[i].get(ms)) for i in steps) + f" at {ms} ms (published "
        f"{fmt(same.get(ms))})"
        for ms in horizons
    ]
    return f" {group.label} at each validation ({when}): " + ", ".join(at) + "."


def target_paragraph(results: Results, protocol: str, targets: dict, notes: dict) -> list[str]:
    """The target and the rows that miss it, with the notes saying why."""
    judged = hl.verdicts(results, results.groups, protocol, targets)
    if not (judged := {g: j for g, j in judged.items() if j.status != "-"}):
        return []
    goal = ", ".join(f"{d} {t:.2f}" for d, t in targets.items())
    text = (
        "**Reproduction target.** A trained row reproduces its paper when its average is within "
        f"the target of the published same-set average at every published horizon ({goal} "
        f"radians; {PROTOCOLS.get(protocol, protocol)}), for both checkpoints, against the "
        "reference its verdict names. "
    )
    if unjudged := [g.label for g, j in judged.items() if j.status == "not judged"]:
        text += (
            "Not judged (their paper prints an average only, over all of its actions, so there "
            f"is no same-set value): {', '.join(unjudged)}. "
        )
    missed = {g: j for g, j in judged.items() if j.status == "misses"}
    if not missed and len(unjudged) < len(judged):
        text += "Every trained row with a published same-set average meets it."
    if missed:
        labels = dict.fromkeys(g.label for g in missed)  # a label's budgets share its note
        why = [f"{label} ({notes.get(label, 'no explanation given')})" for label in labels]
        text += "Rows that miss it: " + "; ".join(why) + "."
    text += "".join(_validation_text(results, g, protocol, j) for g, j in missed.items())
    return [text, ""]


def data_lines(results: Results) -> list[str]:
    """What this data copy lacks, and the published values that are slips of the papers."""
    everyone = [r for g in results.entries for r in g.runs]
    missing = sorted({m for r in everyone for m in r.get("missing_files") or []})
    lines = [
        f"**Data copy.** It lacks {len(missing)} file(s) of the full archives; training used what "
        "exists (`data.allow_partial=true`), actions without test files are absent: "
        + ", ".join(f"`{m}`" for m in missing)
    ] * bool(missing)
    shown = set()
    for group in hl.headline_groups(results):
        evaluated, files = results.actions(group, judged=False), results.files[group].items()
        short = [f"{a} {p} of {n}" for a, (p, n) in files if p < n and a in evaluated]
        if short and group.dataset not in shown:
            shown.add(group.dataset)
            lines.append(
                f"- {group.dataset}: training files of the evaluated actions present (of the full "
                "archive's): " + ", ".join(short) + "."
            )
        for ref in results.refs[group]:
            if slips := results.slips_in(ref, evaluated):
                lines.append(
                    f"- {group.label}: the published values ({ref.key}) of {', '.join(slips)} are "
                    "slips of the paper (shared docs/published_results.md): "
                    + "; ".join(slips.values())
                    + ". Left out of the same-set averages, on both sides."
                )
    if len(cells := results.slip_cells):
        by_action = cells.groupby(["key", "dataset", "action"], sort=False).ms.agg(list)
        found = "; ".join(
            f"{action} ({fr.ms_list(ms)})" for (_, _, action), ms in by_action.items()
        )
        keys = ", ".join(dict.fromkeys(cells.key))
        agree = sorted(set(results.zero_cells.action) - set(cells.action))
        agree = f" The others ({', '.join(agree)}) agree to rounding." if agree else ""
        lines.append(
            f"- Slips found by the protocol ({keys}): zero-velocity is deterministic, so a "
            f"published cell more than {fr.ROUNDING} away from ours on the same windows is a slip "
            f"of the paper: {found}. An action with such a cell is left out of every same-set "
            "zero-velocity average; each cell, with ours beside it, is in "
            f"[published.csv](results/published.csv).{agree}"
        )
    return [*lines, ""] if lines else []


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
    lines = ["# Results", "", *hl.headline(results, first, targets, figures, "#ablations", intro)]
    lines += [f"**Budget.** {budget}", ""] if budget else []
    lines += reading(results) + target_paragraph(results, first, targets, notes or {})
    lines += data_lines(results) + claims_section(results, protocols, "Ablations")
    folders = "Run folders are named relative to the folder that holds them all (the project's, "
    folders += "for runs under its outputs/)."
    lines += ["## Provenance", "", provenance_table(results), "", folders, ""]
    for metric, what in (("euler", "Euler-angle error (radians)"), ("mpjpe", "MPJPE")):
        for k, protocol in enumerate(protocols):
            table = averages_table(results, protocol, metric, published=k == 0)
            lines += [f"## Averages: {what}, {PROTOCOLS.get(protocol, protocol)}", "", table, ""]
    if tables:
        links = [f"[{m} {p}]({tables}/{m}_{p}.csv)" for m in ("euler", "mpjpe") for p in protocols]
        lines += [
            "## Per-action tables",
            "",
            "Each experiment's and baseline's per-action table as CSV (mean and std over the "
            "seeds, the published value, notes on absent and untrained actions; MPJPE in mm on "
            f"H3.6M, skeleton units on CMU): {', '.join(links)}.",
            "",
        ]
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
