"""The headline of the results page and the README's Results block: one table of every
trained experiment (ours, best and last checkpoints, mean ± std over seeds; each published
reference's same-set average with ours minus it; the verdict), its footnotes and a figure of
error against horizon. The page (page.py) opens with it; the README block is it alone, written
between the file's markers. What the numbers mean is decided in verdicts.py; this file only
lays them out.
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path

from src.lit.factory import git_commit
from src.reporting.claims import ABLATIONS
from src.reporting.groups import Group
from src.reporting.plots import Curve, horizon_panels
from src.reporting.published import known_slips
from src.reporting.seed_table import Stat
from src.reporting.tables import fmt, printed_scope
from src.reporting.verdicts import (
    HORIZONS,
    PROTOCOLS,
    SELECTIONS,
    TARGETS,
    Reference,
    beyond,
    judge,
    mean_average,
    printed_gap,
    references,
    seed_table,
    signed,
)

SUPERSCRIPTS = str.maketrans("0123456789", "⁰¹²³⁴⁵⁶⁷⁸⁹")
ABLATIONS_HEADING = "Ablations"


def _mark(n: int) -> str:
    return str(n).translate(SUPERSCRIPTS)


def stat_cells(average: dict[int, Stat] | None, decimals: int) -> list[str]:
    average = average or {}
    return [average[ms].format(decimals) if ms in average else "-" for ms in HORIZONS]


def _ms_list(horizons: list[int]) -> str:
    return ", ".join(str(ms) for ms in horizons) + " ms"


def page_order(groups: list[Group]) -> list[Group]:
    """The page's order: Human3.6M's rows, then CMU's, then any other data (both papers' order),
    the ablations last; otherwise as found (records are read in file-name order, which would
    put li2018_cmu first)."""
    rank = {"h36m": 0, "cmu": 1}
    return sorted(groups, key=lambda g: (g.run_name in ABLATIONS, rank.get(g.dataset, 2)))


def headline_groups(groups: list[Group]) -> list[Group]:
    """The groups of the headline: all but Li et al.'s ablations, which have their section
    (and all of them when nothing else was trained)."""
    return [g for g in groups if g.run_name not in ABLATIONS] or list(groups)


def _reference_verdict(missed: dict[str, list[int]], target: float) -> str:
    if not any(missed.values()):
        return f"within {target:.2f}"
    if missed["best"] == missed["last"]:
        return f"beyond {target:.2f} at {_ms_list(missed['best'])}"
    return f"beyond {target:.2f}: " + "; ".join(
        f"{s} {_ms_list(missed[s])}" for s in SELECTIONS if missed[s]
    )


def headline_table(
    groups: list[Group], protocol: str, targets: dict[str, float], ablations_link: str | None
) -> tuple[list[str], list[str]]:
    """(table lines, footnote lines) of the headline."""
    horizons = " | ".join(f"{ms} ms" for ms in HORIZONS)
    lines = [
        f"| experiment | data | row | n | {horizons} | verdict |",
        "|---|---|---|---:|" + "---:|" * len(HORIZONS) + "---|",
    ]
    footnotes: list[str] = []

    def footnote(text: str) -> str:
        if text not in footnotes:
            footnotes.append(text)
        return _mark(footnotes.index(text) + 1)

    for group in headline_groups(groups):
        target = targets.get(group.dataset)
        verdict = judge(group, protocol, target)
        label = group.label
        if group.settings:
            settings = ", ".join(f"{k}={v}" for k, v in group.settings.items())
            label += footnote(f"{group.label}: {settings}.")
        tables = {s: seed_table(group, s, protocol, "euler") for s in SELECTIONS}
        for selection in SELECTIONS:
            table = tables[selection]
            if selection == "best":
                text = _verdict_text(group, verdict, footnote)
                first = [label, group.dataset]
            else:
                text, first = "", ["", ""]
            lines.append(
                f"| {' | '.join(first)} | ours, {selection} | {table.n} | "
                + " | ".join(stat_cells(table.average(), 2))
                + f" | {text} |"
            )
        for reference in references(group):
            lines.append(_reference_row(group, reference, protocol, target))
    notes = [f"{_mark(k + 1)} {text}" for k, text in enumerate(footnotes)]
    ablations = [g for g in groups if g.run_name in ABLATIONS]
    if ablations and ablations_link and len(headline_groups(groups)) < len(groups):
        notes.append(
            f"Li et al.'s ablations ({len(ablations)} trained "
            f"{'row' if len(ablations) == 1 else 'rows'}: Tables 5 and 6, Figure 4) "
            f"are compared with li2018_h36m, claim by claim, under [{ABLATIONS_HEADING}]"
            f"({ablations_link})."
        )
    return lines, notes


def _verdict_text(group: Group, verdict, footnote) -> str:
    if verdict.status == "not judged":
        return f"not judged ({verdict.why})"
    if verdict.reference is None:
        return verdict.status
    chosen = verdict.reference
    text = f"**{verdict.status}**, judged against {chosen.name}"
    if len(references(group)) > 1:
        about = f" ({chosen.about})" if chosen.about else ""
        text += footnote(f"{group.label}: judged against {chosen.name}{about}: {verdict.why}.")
    return text


def _reference_row(group: Group, reference: Reference, protocol: str, target) -> str:
    best = seed_table(group, "best", protocol, "euler", reference)
    last = seed_table(group, "last", protocol, "euler", reference)
    same = best.published_same_set()
    ours = {s: mean_average(t) for s, t in (("best", best), ("last", last))}
    name = f"{reference.name}, {len(best.evaluated)} actions"
    slips = known_slips(reference.key, best.evaluated)
    if slips:
        name += f" incl. slips ({', '.join(slips)})"
    if not same:
        printed = best.published_as_printed()
        cells = [fmt(printed.get(ms), 2) for ms in HORIZONS]
        return (
            f"|  |  | {reference.name}, as printed ({printed_scope(reference.published)}) | | "
            + " | ".join(cells)
            + " | no same-set value: not judged |"
        )
    cells = []
    for ms in HORIZONS:
        if ms not in same:
            cells.append("-")
            continue
        gaps = ", ".join(
            signed(printed_gap(ours[s][ms], same[ms])) for s in SELECTIONS if ms in ours[s]
        )
        cells.append(f"{same[ms]:.2f} ({gaps})")
    verdict = "-"
    if target is not None:
        missed = {s: beyond(ours[s], same, target) for s in SELECTIONS}
        verdict = _reference_verdict(missed, target)
    return f"|  |  | {name} | | " + " | ".join(cells) + f" | {verdict} |"


def headline(
    groups: list[Group],
    protocol: str,
    targets: dict[str, float],
    figure: str | None,
    ablations_link: str | None,
    intro: str,
) -> list[str]:
    """The headline's lines: intro, legend, table, footnotes and figure."""
    goal = ", ".join(f"{t:.2f} rad on {d}" for d, t in targets.items())
    table, notes = headline_table(groups, protocol, targets, ablations_link)
    lines = [
        intro,
        "",
        "Ours: mean ± std over n seeds, best checkpoint (selected on the test windows, as the "
        "papers did) and last. Published: the paper's average over the same actions (ours minus "
        f"it: best, last). Reproduces: both within {goal} at every published horizon.",
        "",
        *table,
        "",
    ]
    if notes:  # one list: no blank line between footnotes
        lines += [f"- {note}" for note in notes] + [""]
    if figure:
        lines += [f"![Average Euler error against horizon, ours and published]({figure})", ""]
    return lines


def headline_figure(groups: list[Group], protocol: str):
    """Error against horizon, one panel per dataset: ours (best, mean ± std over seeds; last
    dotted) and each published same-set average (dashed), per headline experiment."""
    panels: dict[str, list[Curve]] = {}
    for k, group in enumerate(headline_groups(groups)):
        curves = panels.setdefault(group.dataset, [])
        for selection, style in (("best", "-"), ("last", ":")):
            average = seed_table(group, selection, protocol, "euler").average() or {}
            values = {ms: s.mean for ms, s in average.items()}
            std = {ms: s.std for ms, s in average.items() if s.std is not None}
            if values:
                curves.append(
                    Curve(f"{group.label}, ours {selection}", values, std or None, k, style)
                )
        for j, reference in enumerate(references(group)):
            same = seed_table(group, "best", protocol, "euler", reference).published_same_set()
            if same:
                curves.append(Curve(reference.name, same, None, k, "--" if j == 0 else "-."))
    panels = {d: c for d, c in panels.items() if c}
    if not panels:
        return None
    where = PROTOCOLS.get(protocol, protocol)
    return horizon_panels([(f"{d}: {where}", c) for d, c in panels.items()])


def anchor(heading: str) -> str:
    """GitHub's anchor of a heading made of words and spaces."""
    return heading.lower().replace(" ", "-")


def readme_block(
    groups: list[Group],
    protocol: str,
    commit: str | None = None,
    targets: dict[str, float] | None = None,
    figure: str | None = None,
    page: str = "docs/results.md",
) -> str:
    """The README's Results block: the page's headline, linking to the page for the rest."""
    targets = TARGETS if targets is None else targets
    intro = (
        f"Generated by `python -m src.report` on {dt.date.today()} at commit "
        f"{commit or git_commit()}. Average Euler error (rad) over the evaluated actions, "
        f"{PROTOCOLS.get(protocol, protocol)}; budget, provenance, per-action tables, other "
        f"protocols, MPJPE: [{page}]({page})."
    )
    lines = headline(
        groups, protocol, targets, figure, f"{page}#{anchor(ABLATIONS_HEADING)}", intro
    )
    return "\n".join(lines).rstrip("\n")


def check_block(path: Path, name: str) -> str:
    """The text of `path`, which must hold `<!-- name:start -->` and `<!-- name:end -->`."""
    if not path.is_file():
        raise SystemExit(f"error: {path} does not exist (it should hold the {name} markers)")
    content = path.read_text()
    start, end = f"<!-- {name}:start -->", f"<!-- {name}:end -->"
    if start not in content or end not in content:
        raise SystemExit(f"error: {path} has no {start} ... {end} markers")
    return content


def replace_block(path: Path, name: str, text: str) -> None:
    """Replace what lies between `<!-- name:start -->` and `<!-- name:end -->` in `path`."""
    content = check_block(path, name)
    start, end = f"<!-- {name}:start -->", f"<!-- {name}:end -->"
    head, rest = content.split(start, 1)
    _, tail = rest.split(end, 1)
    path.write_text(f"{head}{start}\n{text}\n{end}{tail}")
