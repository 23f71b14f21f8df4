"""The results page (docs/results.md) and its per-action CSV files: the headline (headline.py)
first, then the budget, how to read the numbers, the ablation claims (claims.py), provenance,
the averages of each protocol and metric, the CSVs and the command that made the page.
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import pandas as pd

from src.lit.factory import ConfigError
from src.reporting.claims import claims_section
from src.reporting.frame import (
    HORIZONS,
    PROTOCOLS,
    SELECTION_LABELS,
    SELECTIONS,
    Results,
    missing_of,
    training_files,
)
from src.reporting.groups import Group
from src.reporting.headline import COLS, headline, headline_groups, span, stat_cells, verdicts
from src.reporting.published import known_slips
from src.reporting.tables import AVERAGE, fmt, markdown, same_set_average


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
            rows.append(
                [
                    group.label if trained else f"{group.label} ({group.kind})",
                    str(r["seed"]) if trained else "-",
                    f"`{r['path']}`" if trained else "-",
                    r.get("commit") or "-",
                    f"{group.iterations:,}" if trained else "-",
                    span([r["iterations_of"]["best"]]) if trained else "-",
                    _wall_time(r) if trained else "-",
                    r.get("device") or "-",
                    r.get("archive_sha256", "-"),
                    f"{missing} (see above)" if missing else "none",
                    "; ".join(r.get("notes", [])) or "-",
                ]
            )
    columns = ["experiment", "seed", "run folder", "commit", "iterations", "best at"]
    columns += ["wall time", "device", "data archive (sha256)", "missing files", "notes"]
    return markdown(pd.DataFrame(rows, columns=columns))


def averages_table(results: Results, protocol: str, metric: str, published: bool) -> str:
    """Every group's average over its evaluated actions, best and last; with `published`, each
    reference's same-set average and its own as printed."""
    decimals, rows = (2 if metric == "euler" else 1), []
    for group in results.entries:
        trained, last = group.kind == "trained", f"{group.iterations:,}"
        best = f"{span(r.get('iterations_of', {}).get('best') for r in group.runs)} of {last}"
        for s in SELECTIONS if trained else ("-",):
            n, budget = str(len(group.runs)), best if s == "best" else last
            n, budget = (n, budget) if trained else ("-", "-")
            cells = stat_cells(results.average(group, protocol, s, metric), decimals)
            rows.append(
                [group.label, group.dataset, SELECTION_LABELS.get(s, "-"), n, budget, *cells]
            )
        evaluated = results.actions(group, judged=False)
        for ref in results.references(group) if published and metric == "euler" else ():
            slips = known_slips(ref.key, evaluated)
            flag = f" (includes slips of the paper: {', '.join(slips)})" if slips else ""
            n = len(set(ref.published) - {AVERAGE})
            same = same_set_average(ref.published, evaluated, HORIZONS)
            printed = ref.published.get(AVERAGE, {})
            for what, values in (
                (f"same {len(evaluated)} actions{flag}", same),
                (f"as printed (all {n or 'of its'} actions)", printed),
            ):
                if values:
                    label = f"{group.label}: published ({ref.key}), {what}"
                    cells = [fmt(values.get(ms)) for ms in HORIZONS]
                    rows.append([label, group.dataset, "paper", "-", "paper", *cells])
    columns = ["experiment", "dataset", "checkpoint", "n", "iterations", *COLS]
    return markdown(pd.DataFrame(rows, columns=columns))


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
        a or (gone if not t else "")
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


def _validation_text(results: Results, group: Group, protocol: str, judgement) -> str:
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
        files = training_files(group.runs[0]["config"], evaluated, missing_of(group))
        short = [f"{a} {p} of {n}" for a, (p, n) in files.items() if p < n]
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
