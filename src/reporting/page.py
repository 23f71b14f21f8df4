"""The results page (docs/results.md), its per-action CSV files and figures, and the README's
Results block, laid out from `Results` (frame.py), which decides what the numbers mean.

The page opens with the headline (also the README block): every trained experiment at each
budget, its verdict, the published same-set averages with ours minus them, the zero-velocity
yardstick and why a row misses. Then the budget, how to read the numbers, the ablation claims,
provenance, the averages of each protocol and metric, the per-action CSVs and the command.
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import pandas as pd

from src.lit.factory import ConfigError
from src.plots import Curve, line_panels
from src.reporting.claims import claims_section
from src.reporting.frame import (
    HORIZONS,
    PROTOCOLS,
    SELECTION_LABELS,
    SELECTIONS,
    Results,
    missing_of,
    printed_gap,
    signed,
    stat,
    training_files,
)
from src.reporting.groups import Group
from src.reporting.published import REFERENCE_CODE_CHECKED, known_slips
from src.reporting.tables import AVERAGE, fmt, markdown, same_set_average

SUPERSCRIPTS = str.maketrans("0123456789", "⁰¹²³⁴⁵⁶⁷⁸⁹")
COLS = [f"{ms} ms" for ms in HORIZONS]
TITLES = (
    "Average Euler error against horizon, ours and published",
    "Mean validation error at 400 and 1000 ms against iteration, published as lines",
)


def _cells(average: dict, decimals: int = 2) -> list[str]:
    return [stat(*average[ms], decimals) if ms in average else "-" for ms in HORIZONS]


def _range(values) -> str:
    known = sorted({v for v in values if v is not None})
    return "-" if not known else f"{known[0]:,}" + (f"–{known[-1]:,}" if known[1:] else "")


def _ms(horizons: list[int]) -> str:
    return ", ".join(map(str, horizons)) + " ms"


def headline_groups(results: Results) -> list[Group]:
    """All but Li et al.'s ablations, which have their section (all when nothing else)."""
    return [g for g in results.groups if not g.ablation] or list(results.groups)


def verdicts(results: Results, groups, protocol: str, targets: dict) -> dict:
    """{g: judgement} of each of `groups` that gets a verdict: an experiment's longest budget
    (groups come longest first)."""
    judged, seen = {}, set()
    for group in groups:
        if (group.label, group.dataset) not in seen:
            seen.add((group.label, group.dataset))
            g = results.g_of(group)
            judged[g] = results.judge(g, protocol, targets.get(group.dataset))
    return judged


def _verdict(results: Results, g: int, judgement, mark) -> str:
    if judgement is None:
        return "shorter budget"
    if judgement.status == "not judged":
        return f"not judged ({judgement.why})"
    if (ref := judgement.reference) is None:
        return judgement.status
    text = f"**{judgement.status}**, judged against {ref.name}"
    if len(results.references(g)) > 1:
        about = f" ({ref.about})" if ref.about else ""
        text += mark(f"{results.label(g)}: judged against {ref.name}{about}: {judgement.why}.")
    return text


def headline_table(results: Results, protocol: str, targets: dict, link: str | None):
    """(table, footnotes, why-rows-miss lines) of the headline."""
    rows, notes = [], []

    def mark(text: str) -> str:
        notes.append(text) if text not in notes else None
        return str(notes.index(text) + 1).translate(SUPERSCRIPTS)

    def add(experiment="", data="", iterations="", row="", n="", cells=(), verdict=""):
        rows.append([experiment, data, iterations, row, n, *cells, verdict])

    groups = headline_groups(results)
    judged = verdicts(results, groups, protocol, targets)
    for k, group in enumerate(groups):
        g, label = results.g_of(group), group.label
        if group.settings:
            settings = ", ".join(f"{a}={v}" for a, v in group.settings.items())
            label += mark(f"{label}: {settings}.")
        actions, untrained, n = results.judged_actions(g), results.untrained_of(g), len(group.runs)
        if untrained:
            label += mark(
                f"{group.label}: {', '.join(untrained)} has no training files in this copy: left "
                f"out of the average the verdict judges ({len(actions)} actions, the published one "
                f"likewise), shown in the per-action tables and the rows 'all "
                f"{len(results.evaluated[g])} actions'."
            )
        verdict, budget = _verdict(results, g, judged.get(g), mark), f"{group.iterations:,}"
        for s in SELECTIONS:
            best = s == "best"
            add(label if best else "", group.dataset if best else "", budget, f"ours, {s}",
                str(n), _cells(results.average(g, protocol, s, judged=True)), verdict * best)  # fmt: skip
        for s in SELECTIONS if untrained else ():
            add(iterations=budget, row=f"ours, {s}, all {len(results.evaluated[g])} actions",
                n=str(n), cells=_cells(results.average(g, protocol, s)))  # fmt: skip
        ours = {s: results.means(g, protocol, s, judged=True) for s in SELECTIONS}
        for ref in results.references(g):
            if not (same := results.same_set(g, ref)):
                printed = ref.published.get(AVERAGE, {})
                add(row=f"{ref.name}, as printed (all of its actions)", verdict="not judged",
                    cells=[fmt(printed.get(ms)) for ms in HORIZONS])  # fmt: skip
                continue
            slips = known_slips(ref.key, actions)
            name = f"{ref.name}, {len(actions)} actions" + (
                f" incl. slips ({', '.join(slips)})" if slips else "")  # fmt: skip
            gaps = {ms: ", ".join(signed(printed_gap(ours[s][ms], v)) for s in SELECTIONS)
                    for ms, v in same.items()}  # fmt: skip
            cells = [f"{same[ms]:.2f} ({gaps[ms]})" if ms in same else "-" for ms in HORIZONS]
            target, text = targets.get(group.dataset), "-"
            if target is not None:
                missed = results.missed(g, protocol, ref, target)
                text = f"within {target:.2f}" if not any(missed.values()) else (
                    f"beyond {target:.2f} at {_ms(missed['best'])}"
                    if missed["best"] == missed["last"] else f"beyond {target:.2f}: "
                    + "; ".join(f"{s} {_ms(missed[s])}" for s in SELECTIONS if missed[s]))  # fmt: skip
            add(row=name, cells=cells, verdict=text)
        zero = results.find("zero_velocity", group.dataset)
        if zero is not None and (k + 1 == len(groups) or groups[k + 1].dataset != group.dataset):
            add("zero-velocity", group.dataset, "-", f"baseline, {len(results.judged_actions(zero))}"
                " actions", "-", _cells(results.average(zero, protocol, "-", judged=True)),
                "the yardstick")  # fmt: skip
    columns = ["experiment", "data", "iterations", "row", "n", *COLS, "verdict"]
    footnotes = [f"{str(k + 1).translate(SUPERSCRIPTS)} {t}" for k, t in enumerate(notes)]
    if link and (ablations := [g for g in results.groups if g.ablation]) and len(groups) < len(
            results.groups):  # fmt: skip
        footnotes.append(
            f"Li et al.'s ablations ({len(ablations)} trained "
            f"{'row' if len(ablations) == 1 else 'rows'}: Tables 5 and 6, Figure 4) are compared "
            f"with li2018_h36m, claim by claim, under [Ablations]({link})."
        )
    why = [results.diagnosis(g, protocol, j, REFERENCE_CODE_CHECKED.get(results.entries[g].run_name))
           for g, j in judged.items() if j.status == "misses"]  # fmt: skip
    return markdown(pd.DataFrame(rows, columns=columns)), footnotes, why


def headline(results, protocol, targets, figures, link, intro) -> list[str]:
    """The headline's lines: intro, legend, table, footnotes, why rows miss, figures."""
    goal = ", ".join(f"{t:.2f} rad on {d}" for d, t in targets.items())
    table, notes, why = headline_table(results, protocol, targets, link)
    lines = [
        intro,
        "",
        "Ours: mean ± std over n seeds, best checkpoint (selected on the test windows, as the "
        "papers did) and last. Published: the paper's average over the same actions (ours minus "
        f"it: best, last). Reproduces: both within {goal} at every published horizon.",
        "",
        table,
        "",
        *[f"- {note}" for note in notes],
    ]
    lines += ["", "**Why rows miss.**", *[f"- {text}" for text in why]] if why else []
    lines += [""] + [f"![{t}]({f})" for t, f in zip(TITLES, figures, strict=False) if f]
    return [*lines, ""] if any(figures) else lines


def readme_block(results, protocol, commit, targets, figure=None, page="docs/results.md") -> str:
    """The README's Results block: the page's headline, linking to the page for the rest."""
    intro = (
        f"Generated by `python -m src.report` on {dt.date.today()} at commit {commit}: average "
        f"Euler error (rad), {PROTOCOLS.get(protocol, protocol)}; the rest in [{page}]({page})."
    )
    lines = headline(results, protocol, targets, [figure], f"{page}#ablations", intro)
    return "\n".join(lines).rstrip("\n")


def replace_block(path: Path, name: str, text: str | None = None) -> None:
    """Replace what lies between `<!-- name:start -->` and `<!-- name:end -->` in `path`;
    text=None only checks that the markers are there."""
    start, end = f"<!-- {name}:start -->", f"<!-- {name}:end -->"
    content = Path(path).read_text() if Path(path).is_file() else ""
    if start not in content or end not in content.split(start, 1)[-1]:
        raise ConfigError(f"readme={path} has no {start} ... {end} markers to write between")
    if text is not None:
        head, rest = content.split(start, 1)
        Path(path).write_text(f"{head}{start}\n{text}\n{end}{rest.split(end, 1)[1]}")


def _wall_time(run: dict) -> str:
    """Training time over all segments; for a run resumed before src.train kept the total, the
    last segment's, said as such."""
    if (total := run.get("train_time_s")) is not None:
        return f"{total / 60:.1f} min"
    if (wall := run.get("wall_time_s")) is None:
        return "-"
    return f"{wall / 60:.1f} min" + (" (last segment)" if run["config"].get("ckpt_path") else "")


def provenance_table(results: Results) -> str:
    rows = []
    for group in results.groups:
        for r in group.runs:
            missing = len(r.get("missing_files") or [])
            rows.append([group.label, str(r["seed"]), f"`{r['path']}`", r.get("commit") or "-",
                         f"{group.iterations:,}", _range([r["iterations_of"]["best"]]),
                         _wall_time(r), r.get("device") or "-", r.get("archive_sha256", "-"),
                         f"{missing} (see above)" if missing else "none",
                         "; ".join(r["notes"]) or "-"])  # fmt: skip
    for e in results.baselines:
        missing = len(e.get("missing_files") or [])
        rows.append([f"{e['label']} ({e.get('kind', 'baseline')})", "-", "-", e.get("commit", "-"),
                     "-", "-", "-", "-", e.get("archive_sha256", "-"),
                     f"{missing} (see above)" if missing else "none", "-"])  # fmt: skip
    columns = ["experiment", "seed", "run folder", "commit", "iterations", "best at", "wall time",
               "device", "data archive (sha256)", "missing files", "notes"]  # fmt: skip
    return markdown(pd.DataFrame(rows, columns=columns))


def averages_table(results: Results, protocol: str, metric: str, published: bool) -> str:
    """Every entry's average over its evaluated actions, best and last; with `published`, each
    reference's same-set average and its own as printed."""
    decimals, rows = (2 if metric == "euler" else 1), []
    for g, entry in enumerate(results.entries):
        trained = isinstance(entry, Group)
        for s in SELECTIONS if trained else ("-",):
            budget = "-" if not trained else f"{entry.iterations:,}" if s == "last" else (
                f"{_range(r['iterations_of']['best'] for r in entry.runs)} of {entry.iterations:,}")  # fmt: skip
            rows.append([results.label(g), results.dataset(g), SELECTION_LABELS.get(s, "-"),
                         str(len(entry.runs)) if trained else "-", budget,
                         *_cells(results.average(g, protocol, s, metric), decimals)])  # fmt: skip
        evaluated = results.evaluated.get(g, [])
        for ref in results.references(g) if published and metric == "euler" else ():
            slips = known_slips(ref.key, evaluated)
            flag = f" (includes slips of the paper: {', '.join(slips)})" if slips else ""
            n = len(set(ref.published) - {AVERAGE})
            for what, values in (
                (f"same {len(evaluated)} actions{flag}", same_set_average(ref.published, evaluated, HORIZONS)),
                (f"as printed (all {n or 'of its'} actions)", ref.published.get(AVERAGE, {})),
            ):  # fmt: skip
                rows += [[f"{results.label(g)}: published ({ref.key}), {what}", results.dataset(g),
                          "paper", "-", "paper", *[fmt(values.get(ms)) for ms in HORIZONS]]] * (
                    bool(values))  # fmt: skip
    columns = ["experiment", "dataset", "checkpoint", "n", "iterations", *COLS]
    return markdown(pd.DataFrame(rows, columns=columns))


def per_action_csv(results: Results, protocol: str, metric: str) -> str:
    """Every entry's per-action table of one protocol and metric as CSV: mean and std (n - 1)
    over the seeds and the published value at each horizon; a note where an action is absent
    or has no training files in this copy."""
    f = results.frame[(results.frame.protocol == protocol) & (results.frame.metric == metric)]
    keys = ["g", "checkpoint", "action"]
    stats = f.groupby([*keys, "horizon"], sort=False).value.agg(["mean", "std", "count"])
    wide = stats[["mean", "std"]].round(4).unstack("horizon")
    wide.columns = [f"{ms} ms" + (" std" if s == "std" else "") for s, ms in wide.columns]
    wide = wide[[f"{ms} ms{x}" for ms in HORIZONS for x in ("", " std") if f"{ms} ms{x}" in wide]]
    out = wide.reset_index()
    notes = f.groupby(keys, sort=False).absent.first().reindex(pd.MultiIndex.from_frame(out[keys]))
    out.insert(3, "n", stats["count"].groupby(level=keys, sort=False).max().to_numpy())
    out.insert(4, "note", [n or ("no training files in this copy" if a in results.untrained_of(g)
                                 else "") for (g, _, a), n in notes.items()])  # fmt: skip
    for ms in HORIZONS if metric == "euler" else ():
        out[f"{ms} ms published"] = [next(iter(refs), None) and refs[0].published.get(a, {}).get(
            ms) for refs, a in zip(map(results.references, out.g), out.action, strict=True)]  # fmt: skip
    out.insert(0, "iterations", [getattr(results.entries[g], "iterations", "") for g in out.g])
    out.insert(0, "data", out.g.map(results.dataset))
    out.insert(0, "experiment", out.pop("g").map(results.label))
    return out.to_csv(index=False)


def figures(results: Results, protocol: str):
    """(error against horizon, a panel per dataset: ours best with its ± band and last dotted,
    each published same-set average dashed; mean validation error at 400 and 1000 ms against
    iteration, a panel per headline experiment with curves, the published values as lines)."""
    horizon: dict[str, list[Curve]] = {}
    validation = []
    for k, group in enumerate(headline_groups(results)):
        g, name = results.g_of(group), f"{group.label}, {group.iterations:,}"
        for s, style in (("best", "-"), ("last", ":")):
            avg = results.average(g, protocol, s, judged=True)
            std = {ms: v[1] for ms, v in avg.items() if v[2] > 1} or None
            curve = Curve(f"{name}, ours {s}", {ms: v[0] for ms, v in avg.items()}, std, k, style)
            horizon.setdefault(group.dataset, []).append(curve)
        refs = results.references(g)
        for j, ref in enumerate(refs):
            if same := results.same_set(g, ref):
                horizon[group.dataset].append(Curve(ref.name, same, None, k, "-." if j else "--"))
        if len(curve := results.validation_means(g, protocol)) > 1:
            # The validations average over every evaluated action: the published value too.
            same = same_set_average(refs[0].published, results.evaluated[g], HORIZONS) if refs else {}
            lines = []
            for c, ms in enumerate((400, 1000)):
                lines.append(Curve(f"{ms} ms", {i: e[ms] for i, e in curve.items()}, color=c))
                if ms in same:
                    ends = dict.fromkeys((min(curve), max(curve)), same[ms])
                    lines.append(Curve(f"{ms} ms, published", ends, color=c, style="--"))
            validation.append((f"{name} iterations, mean over {len(group.runs)} seeds", lines))
    where = PROTOCOLS.get(protocol, protocol)
    first = line_panels([(f"{d}: {where}", c) for d, c in horizon.items()]) if horizon else None
    return first, line_panels(validation, "iterations") if validation else None


def reading(results: Results) -> list[str]:
    """How to read the numbers: the seeds of each row, the runs counted once, the checkpoints,
    the published values."""
    seeds = "; ".join(
        f"{g.label} ({g.dataset}, {g.iterations:,} iterations): {len(g.runs)} seed"
        f"{'s' * (len(g.runs) != 1)} ({', '.join(str(r['seed']) for r in g.runs)})"
        for g in results.groups
    )
    lines = [f"**Seeds.** {seeds or 'no training runs'}. A cell is the mean ± the sample "
             "standard deviation (n - 1) over the seeds' averages; without ±, one seed.", ""]  # fmt: skip
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


def target_paragraph(results: Results, protocol: str, targets: dict, notes: dict) -> list[str]:
    """The reproduction target, the rows that miss it with the notes saying why and their error
    at each validation; that every row meets it only where some row was judged."""
    judged = verdicts(results, results.groups, protocol, targets)
    judged = {g: j for g, j in judged.items() if j.status != "-"}
    if not judged:
        return []
    goal = ", ".join(f"{d} {t:.2f}" for d, t in targets.items())
    text = (
        "**Reproduction target.** A trained row reproduces its paper when its average is within "
        f"the target of the published same-set average at every published horizon ({goal} "
        f"radians; {PROTOCOLS.get(protocol, protocol)}), for both checkpoints, against the "
        "reference its verdict names. "
    )
    if unjudged := [results.label(g) for g, j in judged.items() if j.status == "not judged"]:
        text += ("Not judged (their paper prints an average only, over all of its actions, so "
                 f"there is no same-set value): {', '.join(unjudged)}. ")  # fmt: skip
    missed = {g: j for g, j in judged.items() if j.status == "misses"}
    if not missed and len(unjudged) < len(judged):
        text += "Every trained row with a published same-set average meets it."
    if missed:
        text += "Rows that miss it: " + "; ".join(
            f"{results.label(g)} ({notes.get(results.label(g), 'no explanation given')})"
            for g in missed) + "."  # fmt: skip
    for g, judgement in missed.items():
        if not (means := results.validation_means(g, protocol)):
            continue
        same, steps = results.same_set(g, judgement.reference), list(means)
        when = f"iterations {steps[0]:,} to {steps[-1]:,}" if steps[1:] else f"iteration {steps[0]:,}"
        if len(gaps := {b - a for a, b in zip(steps, steps[1:], strict=False)}) == 1:
            when += f", every {gaps.pop():,}"
        if (n := len(results.entries[g].runs)) > 1:
            when += f"; mean over {n} seeds"
        horizons = sorted({ms for hs in judgement.missed.values() for ms in hs})
        text += f" {results.label(g)} at each validation ({when}): " + ", ".join(
            " ".join(fmt(means[i].get(ms)) for i in steps) + f" at {ms} ms (published "
            f"{fmt(same.get(ms))})" for ms in horizons) + "."  # fmt: skip
    return [text, ""]


def data_lines(results: Results) -> list[str]:
    """What this data copy lacks (the files, the training files of each dataset's evaluated
    actions), and the published values that are slips of the papers."""
    everyone = [r for g in results.groups for r in g.runs] + results.baselines
    missing = sorted({m for e in everyone for m in e.get("missing_files") or []})
    lines = [
        f"**Data copy.** It lacks {len(missing)} file(s) of the full archives; training used what "
        "exists (`data.allow_partial=true`), actions without test files are absent: "
        + ", ".join(f"`{m}`" for m in missing)
    ] * bool(missing)
    shown = set()
    for group in headline_groups(results):
        g = results.g_of(group)
        files = training_files(group.runs[0]["config"], results.evaluated[g], missing_of(group))
        if (short := [f"{a} {p} of {n}" for a, (p, n) in files.items() if p < n]) and (
                group.dataset not in shown):  # fmt: skip
            shown.add(group.dataset)
            lines.append(f"- {group.dataset}: training files of the evaluated actions present (of "
                         "the full archive's): " + ", ".join(short) + ".")  # fmt: skip
        for ref in results.references(g):
            if slips := known_slips(ref.key, results.evaluated[g]):
                lines.append(
                    f"- {group.label}: the published values ({ref.key}) of {', '.join(slips)} are "
                    "slips of the paper (shared docs/published_results.md): "
                    + "; ".join(slips.values()) + ". Kept as printed, so the published averages "
                    "that include them are off too."
                )  # fmt: skip
    return [*lines, ""] if lines else []


def build_page(results, protocols, command, budget, commit, targets, notes=None,
               figures=(None, None), tables=None) -> str:  # fmt: skip
    """The page's markdown; `figures`: the two figures' file names beside it; `tables`: the
    folder of the per-action CSV files (<metric>_<protocol>.csv), relative to the page."""
    first = protocols[0]
    intro = (
        f"Generated by `python -m src.report` on {dt.date.today()} at commit {commit} from the "
        "runs under Provenance (the command is at the end); do not edit by hand. Average "
        f"Euler-angle error (radians) over the evaluated actions, {PROTOCOLS.get(first, first)}."
    )
    lines = ["# Results", "", *headline(results, first, targets, list(figures), "#ablations", intro)]
    lines += [f"**Budget.** {budget}", ""] if budget else []
    lines += reading(results) + target_paragraph(results, first, targets, notes or {})
    lines += data_lines(results) + claims_section(results, protocols, "Ablations")
    lines += ["## Provenance", "", provenance_table(results), "", "Run folders are named "
              "relative to the folder that holds them all (the project's, for runs under its "
              "outputs/).", ""]  # fmt: skip
    for metric, what in (("euler", "Euler-angle error (radians)"),
                         ("mpjpe", "MPJPE (mm on H3.6M, skeleton units on CMU)")):  # fmt: skip
        for k, protocol in enumerate(protocols):
            lines += [f"## Averages: {what}, {PROTOCOLS.get(protocol, protocol)}", "",
                      averages_table(results, protocol, metric, k == 0), ""]  # fmt: skip
    if tables:
        links = ", ".join(f"[{m} {p}]({tables}/{m}_{p}.csv)" for m in ("euler", "mpjpe")
                          for p in protocols)  # fmt: skip
        lines += ["## Per-action tables", "", "Each experiment's and baseline's per-action table "
                  "(mean and std over the seeds, the published value, notes on absent and "
                  f"untrained actions), as CSV: {links}.", ""]  # fmt: skip
    return "\n".join([*lines, "## Command", "", f"`{command}`", ""])
