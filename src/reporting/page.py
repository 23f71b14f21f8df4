"""The results page (docs/results.md), its per-action CSV files and figures, and the README's
Results block. The headline comes first (also the README block): every trained experiment at
each budget, ours at the best and last checkpoints with the published same-set averages and ours
minus them, the verdict, the zero-velocity yardstick, why a row misses. Then the budget, how to
read the numbers, the ablation claims (claims.py), provenance, the averages of each protocol and
metric, the CSVs and the command. What the numbers mean is decided in frame.py.
"""

from __future__ import annotations

import datetime as dt
import os
from pathlib import Path

from src.lit.factory import ConfigError
from src.plots import Curve, line_panels
from src.reporting.claims import claims_section
from src.reporting.frame import (
    HORIZONS,
    PROTOCOLS,
    SELECTION_LABELS,
    SELECTIONS,
    Results,
    ms_list,
    printed_gap,
    signed,
    stat,
)
from src.reporting.published import REFERENCES, known_slips
from src.reporting.tables import AVERAGE, fmt, markdown, same_set_average

SUPERSCRIPTS = str.maketrans("0123456789", "⁰¹²³⁴⁵⁶⁷⁸⁹")
COLS = [f"{ms} ms" for ms in HORIZONS]
TITLES = (
    "Average Euler error against horizon, ours and published",
    "Mean validation error at 400 and 1000 ms against iteration, published as lines",
)


def stat_cells(average: dict, decimals: int = 2) -> list[str]:
    return [stat(*average[ms], decimals) if ms in average else "-" for ms in HORIZONS]


def span(values) -> str:
    known = sorted({v for v in values if v is not None})
    return "-" if not known else f"{known[0]:,}" + (f"–{known[-1]:,}" if known[1:] else "")


def headline_groups(results: Results) -> list:
    """All but Li et al.'s ablations, which have their section (all when nothing else)."""
    return [g for g in results.groups if not g.ablation] or results.groups


def verdicts(results: Results, groups, protocol: str, targets: dict) -> dict:
    """{group: judgement} of an experiment's longest budget (its groups come longest first)."""
    judged = {}
    for group in groups:
        if all((g.label, g.dataset) != (group.label, group.dataset) for g in judged):
            judged[group] = results.judge(group, protocol, targets.get(group.dataset))
    return judged


def _reference_row(results, group, ref, protocol, target) -> tuple[str, list[str], str]:
    """(label, cells, verdict) of a reference: its same-set average with ours minus it (best,
    last), and where that is beyond the target."""
    actions, same = results.actions(group), results.same_set(group, ref)
    if not same:
        cells = [fmt(ref.published.get(AVERAGE, {}).get(ms)) for ms in HORIZONS]
        return f"{ref.name}, as printed (all of its actions)", cells, "not judged"
    name = f"{ref.name}, {len(actions)} actions"
    if slips := known_slips(ref.key, actions):
        name += f" incl. slips ({', '.join(slips)})"
    ours = {s: results.means(group, protocol, s, judged=True) for s in SELECTIONS}
    cells = [
        f"{same[ms]:.2f} ("
        + ", ".join(signed(printed_gap(ours[s][ms], same[ms])) for s in SELECTIONS)
        + ")"
        if ms in same
        else "-"
        for ms in HORIZONS
    ]
    if target is None:
        return name, cells, "-"
    missed = results.missed(group, protocol, ref, target)
    if not any(missed.values()):
        return name, cells, f"within {target:.2f}"
    if missed["best"] == missed["last"]:
        return name, cells, f"beyond {target:.2f} at {ms_list(missed['best'])}"
    where = "; ".join(f"{s} {ms_list(missed[s])}" for s in SELECTIONS if missed[s])
    return name, cells, f"beyond {target:.2f}: {where}"


def headline_table(results: Results, protocol: str, targets: dict, link: str | None):
    """(table, footnotes, why-rows-miss lines) of the headline."""
    rows, notes = [], []

    def mark(text: str) -> str:
        if text not in notes:
            notes.append(text)
        return str(notes.index(text) + 1).translate(SUPERSCRIPTS)

    groups = headline_groups(results)
    judged = verdicts(results, groups, protocol, targets)
    for k, group in enumerate(groups):
        label, n, budget = group.label, str(len(group.runs)), f"{group.iterations:,}"
        if group.settings:
            label += mark(
                f"{label}: " + ", ".join(f"{a}={v}" for a, v in group.settings.items()) + "."
            )
        everything, judged_actions = results.actions(group, False), results.actions(group)
        if untrained := [a for a in everything if a not in judged_actions]:
            label += mark(
                f"{group.label}: {', '.join(untrained)} has no training files in this copy: left "
                f"out of the average the verdict judges ({len(judged_actions)} actions, the "
                f"published one likewise), shown in the per-action tables and the rows 'all "
                f"{len(everything)} actions'."
            )
        j, verdict = judged.get(group), "shorter budget"
        if j is not None and j.status == "not judged":
            verdict = f"not judged ({j.why})"
        elif j is not None and j.reference is None:
            verdict = j.status
        elif j is not None:
            verdict = f"**{j.status}**, judged against {j.reference.name}"
            if len(results.references(group)) > 1:
                about = f" ({j.reference.about})" if j.reference.about else ""
                verdict += mark(
                    f"{group.label}: judged against {j.reference.name}{about}: {j.why}."
                )
        for s in SELECTIONS:
            first = (label, group.dataset) if s == "best" else ("", "")
            cells = stat_cells(results.average(group, protocol, s, judged=True))
            rows.append([*first, budget, f"ours, {s}", n, *cells, verdict if s == "best" else ""])
        for s in SELECTIONS if untrained else ():
            what = f"ours, {s}, all {len(everything)} actions"
            rows.append(
                ["", "", budget, what, n, *stat_cells(results.average(group, protocol, s)), ""]
            )
        for ref in results.references(group):
            name, cells, text = _reference_row(
                results, group, ref, protocol, targets.get(group.dataset)
            )
            rows.append(["", "", "", name, "", *cells, text])
        zero = [
            b for b in results.baselines if (b.label, b.dataset) == ("zero_velocity", group.dataset)
        ]
        if zero and (k + 1 == len(groups) or groups[k + 1].dataset != group.dataset):
            cells = stat_cells(results.average(zero[0], protocol, "-", judged=True))
            what = f"baseline, {len(results.actions(zero[0]))} actions"
            rows.append(["zero-velocity", group.dataset, "-", what, "-", *cells, "the yardstick"])
    footnotes = [f"{str(k + 1).translate(SUPERSCRIPTS)} {t}" for k, t in enumerate(notes)]
    ablations = [g for g in results.groups if g.ablation]
    if link and ablations and len(groups) < len(results.groups):
        footnotes.append(
            f"Li et al.'s ablations ({len(ablations)} trained "
            f"{'row' if len(ablations) == 1 else 'rows'}: Tables 5 and 6, Figure 4) are compared "
            f"with li2018_h36m, claim by claim, under [Ablations]({link})."
        )
    checked = REFERENCES["reference_code_checked"]
    why = [
        results.diagnosis(group, protocol, j, checked.get(group.run_name))
        for group, j in judged.items()
        if j.status == "misses"
    ]
    columns = ["experiment", "data", "iterations", "row", "n", *COLS, "verdict"]
    return markdown(rows, columns), footnotes, why


def headline(results, protocol, targets, figures, link, intro, diagnosis=True) -> list[str]:
    """The headline's lines: intro, legend, table, footnotes, why rows miss (the page's, not
    the README's), figures."""
    goal = ", ".join(f"{t:.2f} rad on {d}" for d, t in targets.items())
    table, notes, why = headline_table(results, protocol, targets, link)
    legend = (
        "Ours: mean ± std over n seeds, best checkpoint (selected on the test windows, as the "
        "papers did) and last. Published: the paper's average over the same actions (ours minus "
        f"it: best, last). Reproduces: both within {goal} at every published horizon."
    )
    lines = [intro, "", legend, "", table, "", *[f"- {note}" for note in notes]]
    if why and diagnosis:
        lines += ["", "**Why rows miss.**", *[f"- {text}" for text in why]]
    lines += [""] + [f"![{t}]({f})" for t, f in zip(TITLES, figures, strict=False) if f]
    return [*lines, ""] if any(figures) else lines


def readme_block(results, protocol, commit, targets, figure=None, page="docs/results.md") -> str:
    """The README's Results block: the page's headline, linking to the page for the rest."""
    intro = (
        f"Generated by `python -m src.report` on {dt.date.today()} at commit {commit}: average "
        f"Euler error (rad), {PROTOCOLS.get(protocol, protocol)}; the rest in [{page}]({page})"
    )
    if any(g.ablation for g in results.groups) and headline_groups(results) != results.groups:
        intro += f", Li et al.'s ablations under [Ablations]({page}#ablations)"
    lines = headline(results, protocol, targets, [figure], None, intro + ".", False)
    return "\n".join(lines).rstrip("\n")


def figures(results: Results, protocol: str):
    """(error against horizon, a panel per dataset: ours best with its ± band and last dotted,
    each published same-set average dashed; mean validation error at 400 and 1000 ms against
    iteration, a panel per headline experiment with curves, the published values as lines)."""
    horizon: dict[str, list[Curve]] = {}
    validation = []
    for k, group in enumerate(headline_groups(results)):
        name, panel = f"{group.label}, {group.iterations:,}", horizon.setdefault(group.dataset, [])
        for s, style in (("best", "-"), ("last", ":")):
            avg = results.average(group, protocol, s, judged=True)
            std = {ms: v[1] for ms, v in avg.items() if v[2] > 1} or None
            mean = {ms: v[0] for ms, v in avg.items()}
            panel.append(Curve(f"{name}, ours {s}", mean, std, k, style))
        for j, ref in enumerate(results.references(group)):
            if same := results.same_set(group, ref):
                panel.append(Curve(ref.name, same, None, k, "-." if j else "--"))
        if len(curve := results.validation_means(group, protocol)) > 1:
            # The validations average over every evaluated action: the published value too.
            ref, evaluated = results.reference(group)[0], results.actions(group, judged=False)
            same = same_set_average(ref.published, evaluated, HORIZONS) if ref else {}
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
    for group in results.entries:
        trained = group.kind == "trained"
        for r in group.runs:
            missing = len(r.get("missing_files") or [])
            commit = r.get("commit") or "-"
            mine = ["-", "-", commit, "-", "-", "-"]
            if trained:
                mine = [str(r["seed"]), f"`{r['path']}`", commit, f"{group.iterations:,}"]
                mine += [span([r["iterations_of"]["best"]]), _wall_time(r)]
            rows.append(
                [group.label if trained else f"{group.label} ({group.kind})", *mine]
                + [r.get("device") or "-", r.get("archive_sha256", "-")]
                + [
                    f"{missing} (see above)" if missing else "none",
                    "; ".join(r.get("notes", [])) or "-",
                ]
            )
    columns = ["experiment", "seed", "run folder", "commit", "iterations", "best at"]
    columns += ["wall time", "device", "data archive (sha256)", "missing files", "notes"]
    return markdown(rows, columns)


def averages_table(results: Results, protocol: str, metric: str, published: bool) -> str:
    """Every group's average over its evaluated actions, best and last; with `published`, each
    reference's same-set average and its own as printed."""
    decimals, rows = (2 if metric == "euler" else 1), []
    for group in results.entries:
        trained, last = group.kind == "trained", f"{group.iterations:,}"
        best = f"{span(r.get('iterations_of', {}).get('best') for r in group.runs)} of {last}"
        for s in SELECTIONS if trained else ("-",):
            n, budget = (
                (str(len(group.runs)), best if s == "best" else last) if trained else ("-", "-")
            )
            cells = stat_cells(results.average(group, protocol, s, metric), decimals)
            rows.append(
                [group.label, group.dataset, SELECTION_LABELS.get(s, "-"), n, budget, *cells]
            )
        evaluated = results.actions(group, judged=False)
        for ref in results.references(group) if published and metric == "euler" else ():
            slips = known_slips(ref.key, evaluated)
            flag = f" (includes slips of the paper: {', '.join(slips)})" if slips else ""
            n = len(set(ref.published) - {AVERAGE})
            for what, values in (
                (
                    f"same {len(evaluated)} actions{flag}",
                    same_set_average(ref.published, evaluated, HORIZONS),
                ),
                (f"as printed (all {n or 'of its'} actions)", ref.published.get(AVERAGE, {})),
            ):
                if values:
                    label = f"{group.label}: published ({ref.key}), {what}"
                    rows.append(
                        [
                            label,
                            group.dataset,
                            "paper",
                            "-",
                            "paper",
                            *map(fmt, map(values.get, HORIZONS)),
                        ]
                    )
    return markdown(rows, ["experiment", "dataset", "checkpoint", "n", "iterations", *COLS])


def per_action_csv(results: Results, protocol: str, metric: str) -> str:
    """Every group's per-action table of one protocol and metric as CSV: mean and std (n - 1)
    over the seeds and the published value at each horizon; a note where an action is absent
    or has no training files in this copy."""
    f = results.frame[(results.frame.protocol == protocol) & (results.frame.metric == metric)]
    keys = ["g", "checkpoint", "action"]
    stats = f.groupby([*keys, "horizon"], sort=False).value.agg(["mean", "std"])
    rows = f.groupby(keys, sort=False)
    out = rows.seed.nunique().rename("n").to_frame()
    gone = "no training files in this copy"
    out["note"] = [
        a or ("" if t else gone)
        for a, t in zip(rows.absent.first(), rows.trained.first(), strict=True)
    ]
    for ms in HORIZONS:
        if ms in stats.index.get_level_values("horizon"):
            cells = stats.xs(ms, level="horizon")
            out[f"{ms} ms"], out[f"{ms} ms std"] = cells["mean"], cells["std"]
    out = out.reset_index()
    if metric == "euler":
        refs = [results.references(results.entries[g])[:1] for g in out.g]
        for ms in HORIZONS:
            pub = [
                r[0].published.get(a, {}).get(ms) if r else None
                for r, a in zip(refs, out.action, strict=True)
            ]
            out[f"{ms} ms published"] = pub
    groups = [results.entries[g] for g in out.pop("g")]
    out.insert(0, "iterations", [g.iterations if g.kind == "trained" else "" for g in groups])
    out.insert(0, "data", [g.dataset for g in groups])
    out.insert(0, "experiment", [g.label for g in groups])
    return out.to_csv(index=False)


def reading(results: Results) -> list[str]:
    """How to read the numbers: each row's seeds, runs counted once, checkpoints, published."""
    seeds = "; ".join(
        f"{g.label} ({g.dataset}, {g.iterations:,} iterations): {len(g.runs)} seed"
        f"{'s' * (len(g.runs) != 1)} ({', '.join(str(r['seed']) for r in g.runs)})"
        for g in results.groups
    )
    lines = [
        f"**Seeds.** {seeds or 'no training runs'}. A cell is the mean ± the sample standard "
        "deviation (n - 1) over the seeds' averages; without ±, one seed.",
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
    """A row that misses at each of its validations, beside the published value: whether the
    miss is one checkpoint's or the whole run's."""
    if not (means := results.validation_means(group, protocol)):
        return ""
    same, steps = results.same_set(group, judgement.reference), list(means)
    when = f"iterations {steps[0]:,} to {steps[-1]:,}" if steps[1:] else f"iteration {steps[0]:,}"
    if len(gaps := {b - a for a, b in zip(steps, steps[1:], strict=False)}) == 1:
        when += f", every {gaps.pop():,}"
    if len(group.runs) > 1:
        when += f"; mean over {len(group.runs)} seeds"
    horizons = sorted({ms for hs in judgement.missed.values() for ms in hs})
    at = [
        " ".join(fmt(means[i].get(ms)) for i in steps) + f" at {ms} ms (published "
        f"{fmt(same.get(ms))})"
        for ms in horizons
    ]
    return f" {group.label} at each validation ({when}): " + ", ".join(at) + "."


def target_paragraph(results: Results, protocol: str, targets: dict, notes: dict) -> list[str]:
    """The reproduction target and the rows that miss it, with the notes saying why; that every
    row meets it only where some row was judged."""
    judged = verdicts(results, results.groups, protocol, targets)
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
        why = [f"{g.label} ({notes.get(g.label, 'no explanation given')})" for g in missed]
        text += "Rows that miss it: " + "; ".join(why) + "."
    text += "".join(_validation_text(results, g, protocol, j) for g, j in missed.items())
    return [text, ""]


def data_lines(results: Results) -> list[str]:
    """What this data copy lacks (the files, the training files of each dataset's evaluated
    actions), and the published values that are slips of the papers."""
    everyone = [r for g in results.entries for r in g.runs]
    missing = sorted({m for r in everyone for m in r.get("missing_files") or []})
    lines = [
        f"**Data copy.** It lacks {len(missing)} file(s) of the full archives; training used what "
        "exists (`data.allow_partial=true`), actions without test files are absent: "
        + ", ".join(f"`{m}`" for m in missing)
    ] * bool(missing)
    shown = set()
    for group in headline_groups(results):
        evaluated = results.actions(group, judged=False)
        files = results.files[group]
        short = [f"{a} {p} of {n}" for a, (p, n) in files.items() if p < n and a in evaluated]
        if short and group.dataset not in shown:
            shown.add(group.dataset)
            lines.append(
                f"- {group.dataset}: training files of the evaluated actions present (of the full "
                "archive's): " + ", ".join(short) + "."
            )
        for ref in results.references(group):
            if slips := known_slips(ref.key, evaluated):
                lines.append(
                    f"- {group.label}: the published values ({ref.key}) of {', '.join(slips)} are "
                    "slips of the paper (shared docs/published_results.md): "
                    + "; ".join(slips.values())
                    + ". Kept as printed, so the published averages that include them are off too."
                )
    return [*lines, ""] if lines else []


def build_page(
    results, protocols, command, budget, commit, targets, notes=None, figures=(), tables=None
) -> str:
    """The page's markdown; `figures`: the two figures' file names beside it; `tables`: the
    folder of the per-action CSV files (<metric>_<protocol>.csv), relative to the page."""
    first, where = protocols[0], PROTOCOLS.get(protocols[0], protocols[0])
    intro = (
        f"Generated by `python -m src.report` on {dt.date.today()} at commit {commit} from the "
        "runs under Provenance (the command is at the end); do not edit by hand. Average "
        f"Euler-angle error (radians) over the evaluated actions, {where}."
    )
    lines = [
        "# Results",
        "",
        *headline(results, first, targets, list(figures), "#ablations", intro),
    ]
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
    """The page at `out`, its figures beside it (<stem>_errors.png, <stem>_validation.png), its
    CSVs in <stem>/ (docs/results.md: docs/results/<metric>_<protocol>.csv) and its headline
    between the results markers of `readme` (None: no README)."""
    tables = out.with_suffix("")
    tables.mkdir(parents=True, exist_ok=True)
    for metric in ("euler", "mpjpe"):
        for protocol in protocols:
            csv = per_action_csv(results, protocol, metric)
            (tables / f"{metric}_{protocol}.csv").write_text(csv)
    names = []
    for figure, kind in zip(figures(results, protocols[0]), ("errors", "validation"), strict=True):
        names.append(f"{out.stem}_{kind}.png" if figure is not None else None)
        if figure is not None:
            figure.savefig(out.with_name(names[-1]))
    page = build_page(
        results, protocols, command, budget, commit, targets, notes, names, tables.name
    )
    out.write_text(page)
    if readme:
        here = readme.resolve().parent
        figure = os.path.relpath(out.with_name(names[0]), here) if names[0] else None
        page = os.path.relpath(out, here)
        replace_block(
            readme, "results", readme_block(results, protocols[0], commit, targets, figure, page)
        )
