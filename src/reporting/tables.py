"""Result tables in the papers' layout: rows = actions (+ "average"), columns = horizons in ms.

Each cell shows our value, optionally with the published value beside it ("0.39 (0.39)").
Actions that could not be evaluated (e.g. S5 files missing from a partial data copy) are printed
as "absent", with the reason in a footnote, never as 0 or NaN. The "average" row is the mean of
the per-action errors over the evaluated actions only (protocol §4.1 step 6), and the table says
which actions those are.

Beside that average stands the published average recomputed from the paper's per-action values
over the same evaluated actions (like for like when some actions are absent), and below it the
paper's average as printed, over all of its actions.

src/reporting/seed_table.py aggregates such tables over seeds.
"""

import csv
import io
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from torch import Tensor

from src.metrics.euler_error import horizon_frame_indices
from src.reporting.published import ReportingError

AVERAGE = "average"
AS_PRINTED = "average_as_printed"


def same_set_average(
    published: Mapping[str, Mapping[int, float]] | None,
    actions: Sequence[str],
    horizons_ms: Sequence[int],
) -> dict[int, float]:
    """Mean of the published per-action values over `actions`, at each horizon where the paper
    gives a value for every one of them (horizons where one is missing are left out).

    This is the published average over the same actions as ours: the papers' own averages cover
    all of their actions, and a data copy may lack some (protocol §4.1 step 6)."""
    if not published or not actions:
        return {}
    out = {}
    for ms in horizons_ms:
        cells = [published.get(a, {}).get(ms) for a in actions]
        if all(v is not None for v in cells):
            out[int(ms)] = sum(cells) / len(cells)
    return out


def fmt(value: float | None, decimals: int) -> str:
    """A number at `decimals` places; '-' for None (no number)."""
    return "-" if value is None else f"{value:.{decimals}f}"


def horizon_header(horizons_ms: Sequence[int]) -> list[str]:
    """The header and alignment rows of a table with one row per action, a column per horizon."""
    return [
        "| action | " + " | ".join(f"{ms} ms" for ms in horizons_ms) + " |",
        "|---" + "|---:" * len(horizons_ms) + "|",
    ]


def absent_row(action: str, note: int, n_horizons: int) -> list[str]:
    """The cells of an action that cannot be evaluated, pointing to the footnote saying why."""
    return [f"{action} [{note}]"] + ["absent"] * n_horizons


def printed_scope(published: Mapping[str, Mapping] | None) -> str:
    """What the paper's printed average covers: "all 15 actions" where the paper gives the
    per-action values, else (an average-only table) "all of its actions"."""
    n = len([a for a in published or {} if a != AVERAGE])
    return f"all {n} actions" if n else "all of its actions"


def printed_average_row(printed: Mapping, horizons_ms, decimals: int) -> list[str]:
    """The paper's average as printed, under ours (nothing when the paper prints none)."""
    if not printed:
        return []
    cells = ["published average, as printed"] + [
        fmt(printed.get(ms), decimals) for ms in horizons_ms
    ]
    return ["| " + " | ".join(cells) + " |"]


def table_footer(table, average_note: str, notes: Mapping[str, int]) -> list[str]:
    """Notes under a table: published values, what the average covers, why actions are absent."""
    lines = []
    if table.published is not None:
        lines += _published_notes(
            table.published_label, len(table.evaluated), printed_scope(table.published)
        )
    lines.append(f"- Average: {average_note}.")
    for reason, number in notes.items():
        who = [a for a in table.actions if table.absent.get(a) == reason]
        lines.append(f"- [{number}] absent ({', '.join(who)}): {reason}")
    return lines


def _published_notes(label: str | None, n_evaluated: int, scope: str) -> list[str]:
    label = label or "published"
    return [
        f"- Cells: ours (published: {label}); '-' where the paper has no number.",
        f"- Published average beside ours: recomputed from the paper's per-action values over the "
        f"same {n_evaluated} evaluated action{'s' if n_evaluated != 1 else ''}, like for like; "
        f"'-' where the paper gives no per-action value for one of them. The row 'published "
        f"average, as printed' is the paper's own average, over {scope}.",
    ]


@dataclass
class ResultTable:
    """One result table. values holds every evaluated action, absent every other action."""

    title: str
    metric: str  # e.g. "Euler-angle error", "MPJPE"
    unit: str  # "rad" or "mm"
    actions: list[str]
    horizons_ms: list[int]
    values: dict[str, dict[int, float]]
    absent: dict[str, str]
    published: dict[str, dict[int, float]] | None = None
    published_label: str | None = None
    decimals: int | None = None  # default: 1 for mm (MPJPE), 2 otherwise (radians)

    def __post_init__(self) -> None:
        self.actions, self.horizons_ms = list(self.actions), [int(ms) for ms in self.horizons_ms]
        if self.decimals is None:
            self.decimals = 1 if self.unit == "mm" else 2
        if not self.horizons_ms:
            raise ReportingError(f"{self.title}: no horizons; the model predicts too few frames")
        if AVERAGE in self.actions:
            raise ReportingError(f"{self.title}: {AVERAGE!r} is computed, not an action")
        for action in self.actions:
            if (action in self.values) == (action in self.absent):
                raise ReportingError(
                    f"{self.title}: action {action!r} must be in exactly one of values and "
                    "absent (with a reason)"
                )
        extra = (set(self.values) | set(self.absent)) - set(self.actions)
        if extra:
            raise ReportingError(f"{self.title}: {sorted(extra)} are not in actions")
        for action, row in self.values.items():
            for ms in self.horizons_ms:
                if ms not in row or not math.isfinite(row[ms]):
                    raise ReportingError(
                        f"{self.title}: {action!r} has no finite value at {ms} ms; list it in "
                        "absent with a reason instead"
                    )

    @property
    def evaluated(self) -> list[str]:
        """Actions with values, in table order."""
        return [a for a in self.actions if a in self.values]

    def average(self) -> dict[int, float] | None:
        """Mean over the evaluated actions of their per-action errors; None if there are none."""
        evaluated = self.evaluated
        if not evaluated:
            return None
        return {
            ms: sum(self.values[a][ms] for a in evaluated) / len(evaluated)
            for ms in self.horizons_ms
        }

    def _published(self, action: str, ms: int) -> float | None:
        if action == AVERAGE:
            return self.published_same_set().get(ms)
        if action == AS_PRINTED:
            return (self.published or {}).get(AVERAGE, {}).get(ms)
        return (self.published or {}).get(action, {}).get(ms)

    def published_same_set(self) -> dict[int, float]:
        """The published average over our evaluated actions (see same_set_average)."""
        return same_set_average(self.published, self.evaluated, self.horizons_ms)

    def published_as_printed(self) -> dict[int, float]:
        """The paper's own average row, over all of its actions; {} if it prints none."""
        row = (self.published or {}).get(AVERAGE, {})
        return {ms: row[ms] for ms in self.horizons_ms if ms in row}

    def _cell(self, value: float, action: str, ms: int) -> str:
        text = f"{value:.{self.decimals}f}"
        if self.published is not None:
            pub = self._published(action, ms)
            text += f" ({pub:.{self.decimals}f})" if pub is not None else " (-)"
        return text

    def _footnotes(self) -> dict[str, int]:
        """Absence reason -> footnote number, in order of first appearance."""
        notes: dict[str, int] = {}
        for action in self.actions:
            if action in self.absent:
                notes.setdefault(self.absent[action], len(notes) + 1)
        return notes

    def _average_note(self) -> str:
        evaluated = self.evaluated
        if not evaluated:
            return "no action was evaluated, so there is no average"
        note = f"mean over the {len(evaluated)} evaluated actions ({', '.join(evaluated)})"
        if self.absent:
            n = len(self.absent)
            note += f"; {n} absent action{'s' if n > 1 else ''} excluded"
        return note

    def to_markdown(self) -> str:
        """The table as GitHub markdown, with footnotes for absent actions and the average."""
        notes = self._footnotes()
        lines = [
            f"**{self.title}**: {self.metric} ({self.unit})",
            "",
            *horizon_header(self.horizons_ms),
        ]
        for action in self.actions:
            if action in self.absent:
                cells = absent_row(action, notes[self.absent[action]], len(self.horizons_ms))
            else:
                row = self.values[action]
                cells = [action] + [self._cell(row[ms], action, ms) for ms in self.horizons_ms]
            lines.append("| " + " | ".join(cells) + " |")
        average = self.average()
        if average is not None:
            cells = [f"**{AVERAGE}**"]
            cells += [self._cell(average[ms], AVERAGE, ms) for ms in self.horizons_ms]
            lines.append("| " + " | ".join(cells) + " |")
            lines += printed_average_row(
                self.published_as_printed(), self.horizons_ms, self.decimals
            )

        lines.append("")
        lines += table_footer(self, self._average_note(), notes)
        return "\n".join(lines) + "\n"

    def to_csv(self, header: bool = True) -> str:
        """Long format: metric, action, ms, value, published, note (one row per action and
        horizon).

        Absent actions have value "absent" and the reason in note; the average row says in note
        which actions it covers. Values are written at full precision. The metric column, and
        header=False for all but the first, let several tables share one CSV (results.csv).
        """
        buf = io.StringIO()
        writer = csv.writer(buf, lineterminator="\n")
        if header:
            writer.writerow(["metric", "action", "ms", "value", "published", "note"])

        def published(action: str, ms: int) -> str:
            pub = self._published(action, ms)
            return "" if pub is None else repr(pub)

        for action in self.actions:
            for ms in self.horizons_ms:
                if action in self.absent:
                    row = [action, ms, "absent", published(action, ms), self.absent[action]]
                else:
                    row = [
                        action,
                        ms,
                        repr(float(self.values[action][ms])),
                        published(action, ms),
                        "",
                    ]
                writer.writerow([self.metric, *row])
        average = self.average()
        if average is not None:
            for ms in self.horizons_ms:
                row = [AVERAGE, ms, repr(average[ms]), published(AVERAGE, ms), self._average_note()]
                writer.writerow([self.metric, *row])
            printed = self.published_as_printed()
            note = f"the paper's own average, over {printed_scope(self.published)}"
            for ms in self.horizons_ms:
                if ms in printed:
                    writer.writerow([self.metric, AS_PRINTED, ms, "", repr(printed[ms]), note])
        return buf.getvalue()

    def to_dict(self) -> dict:
        """JSON-ready dict (horizon keys as strings)."""

        def by_ms(row: Mapping[int, float]) -> dict[str, float]:
            return {str(ms): float(v) for ms, v in row.items()}

        average = self.average()
        return {
            "title": self.title,
            "metric": self.metric,
            "unit": self.unit,
            "decimals": self.decimals,
            "actions": list(self.actions),
            "horizons_ms": list(self.horizons_ms),
            "values": {a: by_ms(self.values[a]) for a in self.evaluated},
            "absent": dict(self.absent),
            "average": None
            if average is None
            else {"actions": self.evaluated, "values": by_ms(average)},
            "published": None
            if self.published is None
            else {a: by_ms(row) for a, row in self.published.items()},
            "published_label": self.published_label,
            # The published average over the same evaluated actions (the average row's actions).
            "published_same_set": None
            if self.published is None
            else by_ms(self.published_same_set()),
        }


def table_from_dict(
    d: Mapping, published: Mapping | None = None, published_label: str | None = None
) -> ResultTable:
    """A ResultTable back from its to_dict() form (e.g. results.json), with `published` (and
    its label) in place of the stored published values; None: no published values."""

    def by_int(row: Mapping) -> dict[int, float]:
        return {int(ms): float(v) for ms, v in row.items()}

    return ResultTable(
        title=d["title"],
        metric=d["metric"],
        unit=d["unit"],
        actions=list(d["actions"]),
        horizons_ms=[int(ms) for ms in d["horizons_ms"]],
        values={a: by_int(row) for a, row in d["values"].items()},
        absent=dict(d["absent"]),
        published=None if published is None else {a: by_int(r) for a, r in published.items()},
        published_label=published_label if published is not None else None,
        decimals=d.get("decimals"),
    )


def results_from_metric(
    values: Tensor,
    actions: Sequence[str],
    frame_ms: float = 40,
    absent: Mapping[str, str] | None = None,
) -> dict[str, dict[int, float]]:
    """{action: {ms: value}} at the table horizons from a metric's compute() output (A, T).

    Actions listed in `absent` are left out. An action with NaN (no windows) that is not listed
    in `absent` raises, so that no action silently disappears from a table; so does a listed
    action that has values.
    """
    absent = dict(absent or {})
    if values.dim() != 2 or values.shape[0] != len(actions):
        raise ReportingError(
            f"values must be (A, T) with A = len(actions) = {len(actions)}, got "
            f"{tuple(values.shape)}"
        )
    horizons = horizon_frame_indices(frame_ms, values.shape[1])
    rows = values.detach().double().cpu().tolist()
    out = {}
    for action, row in zip(actions, rows, strict=True):
        has_values = not any(math.isnan(v) for v in row)
        if action in absent:
            if has_values:
                raise ReportingError(
                    f"action {action!r} is listed as absent ({absent[action]}) but has values"
                )
            continue
        if not has_values:
            raise ReportingError(
                f"action {action!r} has no evaluated windows (NaN); pass it in absent with the "
                "reason (e.g. which data files are missing)"
            )
        out[action] = {ms: row[k] for ms, k in horizons.items()}
    return out
