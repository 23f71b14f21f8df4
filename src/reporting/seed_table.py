"""Tables aggregated over seeds: runs that differ only in their seed give the same ResultTable
layout, each cell the mean ± the sample standard deviation over the seeds, and the table says
how many seeds there are."""

import statistics
from collections.abc import Sequence
from dataclasses import dataclass

from src.reporting.published import ReportingError
from src.reporting.tables import (
    AVERAGE,
    ResultTable,
    absent_row,
    fmt,
    horizon_header,
    printed_average_row,
    same_set_average,
    table_footer,
)


@dataclass(frozen=True)
class Stat:
    """Mean and sample standard deviation (n - 1 denominator) of one cell over n seeds; std is
    None for a single seed."""

    mean: float
    std: float | None
    n: int

    def format(self, decimals: int) -> str:
        text = f"{self.mean:.{decimals}f}"
        return text if self.std is None else f"{text} ± {self.std:.{decimals}f}"


def seed_stat(values: Sequence[float]) -> Stat:
    """Mean ± sample standard deviation of one cell's values over seeds."""
    values = [float(v) for v in values]
    if not values:
        raise ReportingError("no values to aggregate over seeds")
    std = statistics.stdev(values) if len(values) > 1 else None
    return Stat(statistics.fmean(values), std, len(values))


@dataclass
class SeedTable:
    """The same table from runs that differ only in their seed, aggregated over the seeds.

    Each cell is mean ± sample std over the seeds of that action's error; the average row is
    mean ± std of the per-seed averages over the evaluated actions (its mean equals the average
    of the per-action means). All tables must have the same actions, absent actions and
    horizons: seeds of one configuration on one data copy do.
    """

    title: str
    tables: list[ResultTable]
    published: dict[str, dict[int, float]] | None = None
    published_label: str | None = None

    def __post_init__(self) -> None:
        if not self.tables:
            raise ReportingError(f"{self.title}: no tables to aggregate")
        first = self.tables[0]
        for t in self.tables[1:]:
            same = (
                t.actions == first.actions
                and t.horizons_ms == first.horizons_ms
                and set(t.absent) == set(first.absent)
                and (t.metric, t.unit) == (first.metric, first.unit)
            )
            if not same:
                raise ReportingError(
                    f"{self.title}: the seeds' tables differ in actions, absent actions, "
                    "horizons or metric; only runs of one configuration on one data copy can be "
                    "aggregated"
                )

    @property
    def n(self) -> int:
        return len(self.tables)

    @property
    def actions(self) -> list[str]:
        return self.tables[0].actions

    @property
    def horizons_ms(self) -> list[int]:
        return self.tables[0].horizons_ms

    @property
    def absent(self) -> dict[str, str]:
        return self.tables[0].absent

    @property
    def evaluated(self) -> list[str]:
        return self.tables[0].evaluated

    @property
    def decimals(self) -> int:
        return self.tables[0].decimals

    def stats(self, action: str) -> dict[int, Stat]:
        return {
            ms: seed_stat([t.values[action][ms] for t in self.tables]) for ms in self.horizons_ms
        }

    def average(self) -> dict[int, Stat] | None:
        averages = [t.average() for t in self.tables]
        if any(a is None for a in averages):
            return None
        return {ms: seed_stat([a[ms] for a in averages]) for ms in self.horizons_ms}

    def published_same_set(self) -> dict[int, float]:
        return same_set_average(self.published, self.evaluated, self.horizons_ms)

    def published_as_printed(self) -> dict[int, float]:
        row = (self.published or {}).get(AVERAGE, {})
        return {ms: row[ms] for ms in self.horizons_ms if ms in row}

    def _cell(self, stat: Stat, published: float | None) -> str:
        text = stat.format(self.decimals)
        if self.published is not None:
            text += f" ({fmt(published, self.decimals)})"
        return text

    def to_markdown(self) -> str:
        notes: dict[str, int] = {}
        for action in self.actions:
            if action in self.absent:
                notes.setdefault(self.absent[action], len(notes) + 1)
        seeds = f"{self.n} seed{'s' if self.n != 1 else ''}"
        lines = [
            f"**{self.title}**: {self.tables[0].metric} ({self.tables[0].unit}), "
            + (f"mean ± std over {seeds}" if self.n > 1 else seeds),
            "",
            *horizon_header(self.horizons_ms),
        ]
        for action in self.actions:
            if action in self.absent:
                cells = absent_row(action, notes[self.absent[action]], len(self.horizons_ms))
            else:
                pub = (self.published or {}).get(action, {})
                stats = self.stats(action)
                cells = [action] + [self._cell(stats[ms], pub.get(ms)) for ms in self.horizons_ms]
            lines.append("| " + " | ".join(cells) + " |")
        average = self.average()
        if average is not None:
            same = self.published_same_set()
            cells = [f"**{AVERAGE}**"]
            cells += [self._cell(average[ms], same.get(ms)) for ms in self.horizons_ms]
            lines.append("| " + " | ".join(cells) + " |")
            lines += printed_average_row(
                self.published_as_printed(), self.horizons_ms, self.decimals
            )
        lines.append("")
        if self.n > 1:
            lines.append(
                f"- ±: sample standard deviation over the {self.n} seeds (n - 1 denominator); "
                "the average row's is that of the per-seed averages."
            )
        lines += table_footer(self, self.tables[0]._average_note(), notes)
        return "\n".join(lines) + "\n"
