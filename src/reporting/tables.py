"""Result tables in the papers' layout: rows = actions (+ "average"), columns = horizons in ms.

Each cell shows our value, optionally with the published value beside it ("0.39 (0.39)").
Actions that could not be evaluated (e.g. S5 files missing from a partial data copy) are printed
as "absent", with the reason in a footnote, never as 0 or NaN. The "average" row is the mean of
the per-action errors over the evaluated actions only (protocol §4.1 step 6), and the table says
which actions those are.
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
        return (self.published or {}).get(action, {}).get(ms)

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
        header = ["action"] + [f"{ms} ms" for ms in self.horizons_ms]
        lines = [
            f"**{self.title}**: {self.metric} ({self.unit})",
            "",
            "| " + " | ".join(header) + " |",
            "|---" + "|---:" * len(self.horizons_ms) + "|",
        ]
        for action in self.actions:
            if action in self.absent:
                cells = [f"{action} [{notes[self.absent[action]]}]"]
                cells += ["absent"] * len(self.horizons_ms)
            else:
                row = self.values[action]
                cells = [action] + [self._cell(row[ms], action, ms) for ms in self.horizons_ms]
            lines.append("| " + " | ".join(cells) + " |")
        average = self.average()
        if average is not None:
            cells = [f"**{AVERAGE}**"]
            cells += [self._cell(average[ms], AVERAGE, ms) for ms in self.horizons_ms]
            lines.append("| " + " | ".join(cells) + " |")

        lines.append("")
        if self.published is not None:
            label = self.published_label or "published"
            lines.append(
                f"- Cells: ours (published: {label}); '-' where the paper has no number. Published "
                "averages are as printed and may cover a different set of actions."
            )
        lines.append(f"- Average: {self._average_note()}.")
        for reason, number in notes.items():
            who = [a for a in self.actions if self.absent.get(a) == reason]
            lines.append(f"- [{number}] absent ({', '.join(who)}): {reason}")
        return "\n".join(lines) + "\n"

    def to_csv(self) -> str:
        """Long format: action, ms, value, published, note (one row per action and horizon).

        Absent actions have value "absent" and the reason in note; the average row says in note
        which actions it covers. Values are written at full precision.
        """
        buf = io.StringIO()
        writer = csv.writer(buf, lineterminator="\n")
        writer.writerow(["action", "ms", "value", "published", "note"])

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
                writer.writerow(row)
        average = self.average()
        if average is not None:
            for ms in self.horizons_ms:
                row = [AVERAGE, ms, repr(average[ms]), published(AVERAGE, ms), self._average_note()]
                writer.writerow(row)
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
        }


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
