"""The headline of the results page, also the README's Results block: each trained experiment
and budget, ours (best, last) beside the published same-set averages and ours minus them, the
verdict, the zero-velocity yardstick, why a row misses; and the figures."""

from __future__ import annotations

import datetime as dt

import src.reporting.frame as fr
from src.plots import Curve, line_panels
from src.reporting.frame import HORIZONS, PROTOCOLS, SELECTIONS, Results
from src.reporting.published import REFERENCES
from src.reporting.tables import AVERAGE, fmt, markdown

SUPERSCRIPTS = str.maketrans("0123456789", "⁰¹²³⁴⁵⁶⁷⁸⁹")
COLS = [f"{ms} ms" for ms in HORIZONS]
TITLES = (
    "Average Euler error against horizon, ours and published",
    "Mean validation error at 400 and 1000 ms against iteration, published as lines",
)


def stat_cells(average: dict, decimals: int = 2) -> list[str]:
    return [fr.stat(*average[ms], decimals) if ms in average else "-" for ms in HORIZONS]


def span(values) -> str:
    known = sorted({v for v in values if v is not None})
    return "-" if not known else f"{known[0]:,}" + (f"–{known[-1]:,}" if known[1:] else "")


def headline_groups(results: Results) -> list:
    """All but Li et al.'s ablations, which have their section (all when nothing else)."""
    return [g for g in results.groups if not g.ablation] or results.groups


def verdicts(results: Results, groups, protocol: str, targets: dict) -> dict:
    """{group: judgement} of every budget of every experiment."""
    return {g: results.judge(g, protocol, targets.get(g.dataset)) for g in groups}


def where(horizons: dict[str, list[int]]) -> str:
    """'80, 160 ms' where both checkpoints agree, else 'best 80 ms; last 80, 160 ms'."""
    if horizons["best"] == horizons["last"]:
        return fr.ms_list(horizons["best"])
    return "; ".join(f"{s} {fr.ms_list(horizons[s])}" for s in SELECTIONS if horizons[s])


def _reference_row(results, group, ref, protocol, target) -> tuple[str, list[str], str]:
    """(label, cells, verdict): the same-set average, ours minus it, where beyond the target."""
    actions, t = results.actions(group), results.gaps(group, ref, protocol)
    if t.empty:
        cells = [fmt(ref.published.get(AVERAGE, {}).get(ms)) for ms in HORIZONS]
        return f"{ref.name}, as printed (all of its actions)", cells, "not judged"
    name = f"{ref.name}, {len(actions)} actions"
    if slips := results.slips_in(ref, actions):
        kept = len(actions) - len(slips)
        name = f"{ref.name}, {kept} actions (slips left out: {', '.join(slips)})"
    gaps = t[["same", "best gap", "last gap"]].itertuples()
    shown = {ms: f"{same:.2f} ({fr.signed(b)}, {fr.signed(last)})" for ms, same, b, last in gaps}
    cells = [shown.get(ms, "-") for ms in HORIZONS]
    missed = results.missed(group, protocol, ref, target) if target is not None else {}
    if target is None or not any(missed.values()):
        return name, cells, "-" if target is None else f"within {target:.2f}"
    sep = " at " if missed["best"] == missed["last"] else ": "
    return name, cells, f"beyond {target:.2f}{sep}{where(missed)}"


def why_rows_miss(results: Results, judged: dict, protocol: str, notes: dict) -> list[str]:
    """Per experiment that misses, once: the diagnosis of its longest budget if that one misses,
    and the note given for it (`notes=`); the only place either is said."""
    checked, lines = REFERENCES["reference_code_checked"], []
    missing = [g for g, j in judged.items() if j.status == "misses"]
    for label, data in dict.fromkeys((g.label, g.dataset) for g in missing):
        longest = next(g for g in judged if (g.label, g.dataset) == (label, data))  # groups.py
        if longest in missing:
            checks = checked.get(longest.run_name)
            text = results.diagnosis(longest, protocol, judged[longest], checks)
            lines.append(text + (f" Note: {notes[label]}." if label in notes else ""))
        elif label in notes:  # a shorter budget misses, the longest does not: the note alone
            budgets = [
                f"{g.iterations:,}" for g in missing if (g.label, g.dataset) == (label, data)
            ]
            budgets = f"{label} at {' and '.join(budgets)} iterations (the longest reproduces)"
            lines.append(f"{budgets}: {notes[label]}.")
    return lines


def headline_table(results: Results, protocol: str, targets: dict, link: str | None, notes=None):
    """(table, footnotes, why-rows-miss lines) of the headline."""
    rows, marks = [], {}  # footnote -> its number
    mark = lambda text: str(marks.setdefault(text, len(marks) + 1)).translate(SUPERSCRIPTS)  # noqa: E731

    groups = headline_groups(results)
    judged = verdicts(results, groups, protocol, targets)
    for k, group in enumerate(groups):
        label, n, budget = group.label, str(len(group.runs)), f"{group.iterations:,}"
        everything, judged_actions = results.actions(group, False), results.actions(group)
        if untrained := results.untrained_actions(group):
            label += mark(
                f"{group.label}: {', '.join(untrained)} has no training files in this copy: not "
                f"judged (nor in the published average), in the rows 'all {len(everything)} "
                "actions' and the per-action tables."
            )
        j, verdict = judged[group], "-"
        if j.status == "not judged":
            verdict = f"not judged ({j.why})"
        elif j.status != "-":
            ref = j.reference
            others = [r for r in results.refs[group] if r is not ref]
            verdict = f"**{j.status}**, judged against {ref.name}"
            if others or "left out" in j.why:
                also = "; ".join(r.name + (f" ({r.about})" if r.about else "") for r in others)
                also = f"; second reference: {also}" * bool(also)
                verdict += mark(f"{group.label}: judged against {ref.name} ({j.why}){also}.")
        if (no_better := results.no_better_than_zero(group, protocol)) and any(no_better.values()):
            verdict += f"; no better than zero-velocity at {where(no_better)}"
        # The sets named as training's TensorBoard and src.eval name them.
        sets = [f"{len(judged_actions)} trained actions", f"all {len(everything)} actions"]
        ours = [(a, s) for a in ((False, True) if untrained else (False,)) for s in SELECTIONS]
        for i, (all_actions, s) in enumerate(ours):
            what = f"ours, {s}" + f", {sets[all_actions]}" * bool(untrained)
            cells = stat_cells(results.average(group, protocol, s, judged=not all_actions))
            first = [label, group.dataset] if i == 0 else ["", ""]
            rows.append([*first, budget, what, n, *cells, "" if i else verdict])
        for ref in results.refs[group]:
            name, cells, text = _reference_row(
                results, group, ref, protocol, targets.get(group.dataset)
            )
            rows.append(["", "", "", name, "", *cells, text])
        zero = results.zero(group.dataset)
        if zero and (k + 1 == len(groups) or groups[k + 1].dataset != group.dataset):
            cells = stat_cells(results.average(zero, protocol, "-", judged=True))
            what = f"baseline, {len(results.actions(zero))} actions"
            rows.append(["zero-velocity", group.dataset, "-", what, "-", *cells, "the yardstick"])
    footnotes = [f"{str(k).translate(SUPERSCRIPTS)} {t}" for t, k in marks.items()]
    ablations = [g for g in results.groups if g.ablation]
    if link and ablations and len(groups) < len(results.groups):
        footnotes.append(
            f"Li et al.'s ablations ({len(ablations)} trained "
            f"{'row' if len(ablations) == 1 else 'rows'}: Tables 5 and 6, Figure 4) are compared "
            f"with li2018_h36m, claim by claim, under [Ablations]({link})."
        )
    columns = ["experiment", "data", "iterations", "row", "n", *COLS, "verdict"]
    return markdown(rows, columns), footnotes, why_rows_miss(results, judged, protocol, notes or {})


def headline(results, protocol, targets, figures, link, intro, notes=None) -> list[str]:
    """intro, legend, table, footnotes, why rows miss (notes not None: the page's), figures."""
    goal = ", ".join(f"{t:.2f} rad on {d}" for d, t in targets.items())
    table, footnotes, why = headline_table(results, protocol, targets, link, notes)
    legend = (
        "Ours: mean ± std (n - 1) over n seeds, best checkpoint (selected on the test "
        "windows, as the papers did: optimistic) and last. Published: the paper's average over "
        f"the same actions (ours minus it: best, last). Reproduces: both within {goal} at every "
        "published horizon."
    )
    lines = [intro, "", legend, "", table, "", *[f"- {note}" for note in footnotes]]
    if why and notes is not None:
        lines += ["", "**Why rows miss.**", *[f"- {text}" for text in why]]
    lines += [""] + [f"![{t}]({f})" for t, f in zip(TITLES, figures, strict=False) if f]
    return [*lines, ""] if any(figures) else lines


def readme_block(results, protocol, commit, targets, figure=None, page="docs/results.md") -> str:
    intro = (
        f"Generated by `python -m src.report` on {dt.date.today()} at commit {commit}: average "
        f"Euler error (rad), {PROTOCOLS.get(protocol, protocol)}; the rest in [{page}]({page})"
    )
    if any(g.ablation for g in results.groups) and headline_groups(results) != results.groups:
        intro += f", Li et al.'s ablations under [Ablations]({page}#ablations)"
    lines = headline(results, protocol, targets, [figure], None, intro + ".")
    return "\n".join(lines).rstrip("\n")


def figures(results: Results, protocol: str):
    """(error against horizon, a panel per dataset; validation error at 400 and 1000 ms against
    iteration, a panel per experiment with each budget's curves, longest solid), the published
    values dashed."""
    horizon: dict[str, list[Curve]] = {}
    budgets: dict[tuple, list] = {}
    for k, group in enumerate(headline_groups(results)):
        name, panel = f"{group.label}, {group.iterations:,}", horizon.setdefault(group.dataset, [])
        for s, style in (("best", "-"), ("last", ":")):
            avg = results.average(group, protocol, s, judged=True).items()
            std = {ms: v[1] for ms, v in avg if v[2] > 1} or None
            panel.append(Curve(f"{name}, ours {s}", {ms: v[0] for ms, v in avg}, std, k, style))
        for j, ref in enumerate(results.refs[group]):
            if same := results.same_set(group, ref):
                panel.append(Curve(ref.name, same, None, k, "-." if j else "--"))
        if len(curve := results.validation_means(group, protocol)) > 1:
            # The validations average over every evaluated action: the published value too.
            ref = results.reference(group)[0]
            same = results.same_set(group, ref, judged=False) if ref else {}
            budgets.setdefault((group.label, group.dataset), []).append((group, curve, same))
    validation = []
    for (experiment, dataset), curves in budgets.items():  # longest budget first (group order)
        lines, steps = [], [i for _, curve, _ in curves for i in curve]
        for b, (group, curve, _) in enumerate(curves):
            n = len(group.runs)
            seeds = f"mean of {n} seeds" if n > 1 else "one seed"
            for c, ms in enumerate((400, 1000)):
                label = f"{ms} ms, {group.iterations:,} iterations, {seeds}"
                values = {i: e[ms] for i, e in curve.items()}
                lines.append(Curve(label, values, color=c, style=":" if b else "-"))
        same = curves[0][2]  # the same evaluated actions in each budget
        for c, ms in enumerate((400, 1000)):
            if ms in same:
                ends = dict.fromkeys((min(steps), max(steps)), same[ms])
                lines.append(Curve(f"{ms} ms, published", ends, color=c, style="--"))
        validation.append((f"{experiment} ({dataset})", lines))
    where = PROTOCOLS.get(protocol, protocol)
    first = line_panels([(f"{d}: {where}", c) for d, c in horizon.items()]) if horizon else None
    return first, line_panels(validation, "iterations", from_zero=False) if validation else None
