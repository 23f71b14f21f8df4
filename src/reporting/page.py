"""The results page (docs/results.md): layout only.

The page opens with the headline (headline.py, which is also the README's Results block).
Then the budget and how to read the numbers, the ablation claims, the settings compared,
provenance, the per-action tables of the papers' protocol, the other protocols, MPJPE and the
command. What the numbers mean is decided in verdicts.py and claims.py; this file only lays
them out.
"""

from __future__ import annotations

import datetime as dt

from src.lit.factory import git_commit
from src.reporting.claims import claims_section
from src.reporting.groups import Group
from src.reporting.headline import ABLATIONS_HEADING, anchor, headline, headline_groups, stat_cells
from src.reporting.published import known_slips
from src.reporting.seed_table import SeedTable
from src.reporting.tables import fmt, printed_scope, table_from_dict
from src.reporting.verdicts import (
    HORIZONS,
    PROTOCOLS,
    SELECTION_LABELS,
    SELECTIONS,
    TARGETS,
    comparison_lines,
    gap_lines,
    judge,
    references,
    seed_table,
    slip_lines,
    stored_published,
    training_data_line,
    validation_text,
)


def _range(values: list[int | None]) -> str:
    known = sorted({v for v in values if v is not None})
    if not known:
        return "-"
    if len(known) == 1:
        return f"{known[0]:,}"
    return f"{known[0]:,}–{known[-1]:,}"


def summary_table(groups: list[Group], baselines: list[dict], metric: str, protocol: str) -> str:
    decimals = 2 if metric == "euler" else 1
    lines = [
        "| experiment | dataset | checkpoint | seeds | iterations | "
        + " | ".join(f"{h} ms" for h in HORIZONS)
        + " |",
        "|---|---|---|---:|---:|" + "---:|" * len(HORIZONS),
    ]
    for group in groups:
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
                + " | ".join(stat_cells(table.average(), decimals))
                + " |"
            )
        if metric == "euler":
            for reference in references(group):
                table = seed_table(group, "best", protocol, metric, reference)
                lines += _published_rows(group.label, group.dataset, table)
    for entry in baselines:
        result = entry["results"][protocol]
        table_dict = result["tables"][0 if metric == "euler" else 1]
        published = stored_published(table_dict, entry["dataset"]) if metric == "euler" else None
        table = SeedTable(
            entry["label"],
            [table_from_dict(table_dict)],
            published,
            table_dict.get("published_label"),
        )
        lines.append(
            f"| {entry['label']} | {entry['dataset']} | - | - | - | "
            + " | ".join(stat_cells(table.average(), decimals))
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


def _wall_time(run: dict) -> str:
    """Training time over all of a run's segments; for a run resumed from a checkpoint that
    does not hold it (src.train before train_time_s), the last segment's, said as such."""
    total = run.get("train_time_s")
    if total is not None:
        return f"{total / 60:.1f} min"
    wall = run.get("wall_time_s")
    if wall is None:
        return "-"
    return f"{wall / 60:.1f} min" + (" (last segment)" if run["config"].get("ckpt_path") else "")


def provenance_table(groups: list[Group], baselines: list[dict]) -> str:
    lines = [
        "| experiment | seed | run folder | commit | iterations | best at | wall time | device "
        "| data archive (sha256) | missing files | notes |",
        "|---|---:|---|---|---:|---:|---:|---|---|---|---|",
    ]
    for group in groups:
        for r in group.runs:
            missing = r.get("missing_files") or []
            lines.append(
                f"| {group.label} | {r['seed']} | `{r['path']}` | {r.get('commit') or '-'} | "
                f"{_range([r['iterations']])} | {_range([r['iterations_of']['best']])} | "
                f"{_wall_time(r)} | {r.get('device') or '-'} | "
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


def how_to_read(groups: list[Group]) -> list[str]:
    seeds = "; ".join(
        f"{g.label} ({g.dataset}): {len(g.runs)} seed{'s' if len(g.runs) != 1 else ''} "
        f"({', '.join(str(r['seed']) for r in g.runs)})"
        for g in groups
    )
    lines = [
        f"**Seeds.** {seeds or 'no training runs'}. A trained model's cell is the mean ± the "
        "sample standard deviation (n - 1) over its seeds; without ±, one seed. The average "
        "row's ± is that of the per-seed averages.",
        "",
    ]
    left_out = [line for g in groups for line in g.left_out]
    if left_out:
        lines += ["**Runs counted once.** " + "; ".join(left_out) + ".", ""]
    lines += [
        "**Checkpoints.** *best (test-selected)*: the lowest average Euler error at a validation "
        "during training, on the test windows, as both reference implementations and the "
        "papers (protocol section 8): this selection uses test information and is optimistic. "
        "*last (no test info)*: the final iteration, chosen without looking at the test windows.",
        "",
        "**Published values.** The paper's average recomputed from its per-action values over "
        "the actions evaluated here ('same N actions': like for like when this data copy lacks "
        "some), and as printed, over all of its actions. Li et al.'s Tables 5 and 6 print "
        "averages only, so they have no same-set value.",
        "",
    ]
    return lines


def target_paragraph(
    groups: list[Group], protocol: str, targets: dict[str, float], notes: dict[str, str]
) -> list[str]:
    """The reproduction target, which rows miss it, and the notes saying why."""
    checked = [g for g in groups if g.dataset in targets]
    if not checked:
        return []
    judged = [(g, judge(g, protocol, targets[g.dataset])) for g in checked]  # once per row
    missed = [g.label for g, j in judged if j.status == "misses"]
    goal = ", ".join(f"{d} {t:.2f}" for d, t in targets.items())
    text = (
        "**Reproduction target.** A trained row reproduces its paper when its average is within "
        f"the target of the published same-set average at every published horizon ({goal} "
        f"radians; {PROTOCOLS.get(protocol, protocol)}), for both checkpoints, against the "
        "reference its verdict names. "
    )
    unjudged = [g.label for g, j in judged if j.status == "not judged"]
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
    text += "."
    # Whether a miss is one checkpoint's or the whole run's: its error at every validation.
    for group, judgement in judged:
        curve = (
            validation_text(group, protocol, judgement) if judgement.status == "misses" else None
        )
        text += f" {curve}" if curve else ""
    return [text, ""]


def _group_section(
    group: Group, protocol: str, target: float | None, notes: dict[str, str]
) -> list[str]:
    lines = [f"### {group.label} ({group.dataset})", ""]
    if group.settings:
        lines.append(
            "- Settings: " + ", ".join(f"{k}={v}" for k, v in group.settings.items()) + "."
        )
    folders = ", ".join(f"seed {r['seed']}: `{r['path']}`" for r in group.runs)
    lines += [
        f"- Runs: {folders}.",
        "- Best checkpoints at iteration(s) "
        + ", ".join(_range([r["iterations_of"]["best"]]) for r in group.runs)
        + f" of {_range([r['iterations'] for r in group.runs])}.",
    ]
    lines += [f"- {line}." for line in group.left_out]
    for selection in SELECTIONS:
        lines += gap_lines(group, selection, protocol, target)
    line = training_data_line(group, protocol)
    lines += ([line] if line else []) + slip_lines(group, protocol)
    if group.label in notes:
        lines.append(f"- Note: {notes[group.label]}")
    lines.append("")
    lines += _per_action(group, protocol, "euler")
    return lines


def _per_action(group: Group, protocol: str, metric: str) -> list[str]:
    """The group's per-action tables: best and last, with the first reference; then the best
    with each further reference."""
    lines = []
    for selection in SELECTIONS:
        lines += [seed_table(group, selection, protocol, metric).to_markdown(), ""]
    if metric == "euler":
        for reference in references(group)[1:]:
            table = seed_table(group, "best", protocol, metric, reference)
            table.title += f", beside {reference.name}"
            lines += [table.to_markdown(), ""]
    return lines


def _baseline_tables(baselines: list[dict], protocol: str, metric: str) -> list[str]:
    lines = []
    for entry in baselines:
        table_dict = entry["results"][protocol]["tables"][0 if metric == "euler" else 1]
        published = stored_published(table_dict, entry["dataset"]) if metric == "euler" else None
        table = table_from_dict(table_dict, published, table_dict.get("published_label"))
        lines += [
            f"### {entry['label']} ({entry['dataset']}), {PROTOCOLS.get(protocol, protocol)}",
            "",
            table.to_markdown(),
            "",
        ]
    return lines


def build_page(
    groups: list[Group],
    baselines: list[dict],
    protocols: list[str],
    command: str,
    budget: str | None,
    commit: str | None = None,
    targets: dict[str, float] | None = None,
    notes: dict[str, str] | None = None,
    figure: str | None = None,
) -> str:
    targets = TARGETS if targets is None else targets
    notes = notes or {}
    first = protocols[0]
    intro = (
        f"Generated by `python -m src.report` on {dt.date.today()} at commit "
        f"{commit or git_commit()} from the checkpoints of the runs under Provenance (the "
        "command is at the end); do not edit by hand. Average Euler-angle error (radians) over "
        f"the evaluated actions, {PROTOCOLS.get(first, first)}."
    )
    lines = ["# Results", ""]
    lines += headline(groups, first, targets, figure, f"#{anchor(ABLATIONS_HEADING)}", intro)
    if budget:
        lines += [f"**Budget.** {budget}", ""]
    lines += how_to_read(groups)
    lines += target_paragraph(groups, first, targets, notes)
    lines += claims_section(groups, protocols, ABLATIONS_HEADING)
    compared = comparison_lines(groups, first)
    if compared:
        lines += [
            f"## Settings compared ({PROTOCOLS.get(first, first)})",
            "",
            "Runs of one experiment that differ in one setting: the average Euler error over the "
            "evaluated actions (mean over seeds), the later row minus the first; negative means "
            "the later setting has the lower error. With one seed a side, compare a difference "
            "with the spread between seeds of the rows that have several.",
            "",
            *compared,
            "",
        ]
    lines += ["## Provenance", ""]
    lines += [provenance_table(groups, baselines), ""]
    lines += [
        "Run folders are named relative to the folder that holds them all (the project's, for "
        "runs under its outputs/).",
        "",
    ]
    everyone = [r for g in groups for r in g.runs] + baselines
    missing = sorted({m for e in everyone for m in e.get("missing_files") or []})
    if missing:
        lines += [
            f"The data copy lacks {len(missing)} file(s) of the full archives; training used what "
            "exists (`data.allow_partial=true`) and actions without test files are shown as "
            "absent: " + ", ".join(f"`{m}`" for m in missing),
            "",
        ]
    # Per-action tables of the ablations on the papers' protocol only: elsewhere their averages
    # (in the tables of averages) are what the claims use.
    main = headline_groups(groups)
    for k, protocol in enumerate(protocols):
        where = PROTOCOLS.get(protocol, protocol)
        lines += [
            f"## {'Per-action tables' if k == 0 else 'Other protocol'}: {where}",
            "",
            "Averages over the evaluated actions (Euler-angle error, radians), with the baselines:",
            "",
            summary_table(groups, baselines, "euler", protocol),
            "",
        ]
        for group in groups if k == 0 else main:
            if k == 0:
                lines += _group_section(group, protocol, targets.get(group.dataset), notes)
            else:
                lines += [f"### {group.label} ({group.dataset}), {where}", ""]
                lines += _per_action(group, protocol, "euler")
        lines += _baseline_tables(baselines, protocol, "euler")
    lines += ["## MPJPE", "", "Mean per-joint position error: mm on H3.6M, skeleton units on CMU."]
    lines.append("")
    for protocol in protocols:
        lines += [
            f"Averages, {PROTOCOLS.get(protocol, protocol)}:",
            "",
            summary_table(groups, baselines, "mpjpe", protocol),
            "",
        ]
    for protocol in protocols:
        where = PROTOCOLS.get(protocol, protocol)
        for group in main:
            lines += [f"### {group.label} ({group.dataset}), MPJPE, {where}", ""]
            lines += _per_action(group, protocol, "mpjpe")
        lines += _baseline_tables(baselines, protocol, "mpjpe")
    lines += ["## Command", "", f"`{command}`", ""]
    return "\n".join(lines)
