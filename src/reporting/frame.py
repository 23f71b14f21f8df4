"""Every evaluation as one long table, and what the results page concludes from it.

`Results.frame` has one row per run, protocol, checkpoint, metric, action and horizon: group
index `g` (into `Results.entries`: the groups of trained runs, then the baselines), experiment,
dataset, iterations, seed, run, protocol, checkpoint ("best", "last"; "-" for a baseline),
metric, action, horizon, value (NaN where the action is absent), absent (the reason) and
trained (False for an evaluated action this data copy has no training file of). Every table of
the page is a groupby of it: a seed's average over the actions, then mean ± std (n - 1) over
the seeds.

A group is judged against one published reference: the model's own paper, unless its same-set
average includes a known slip of the paper and another reference's does not. The judged average
leaves out the evaluated actions without training files in this copy (CMU washwindow); the
average over all evaluated actions stands beside it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import pandas as pd

from src.reporting.groups import Group
from src.reporting.published import (
    ALSO_PUBLISHED,
    EXPERIMENT_PUBLISHED,
    PAPERS,
    ReportingError,
    known_slips,
    published_for,
)
from src.reporting.tables import same_set_average

HORIZONS = (80, 160, 320, 400, 560, 1000)
SELECTIONS = ("best", "last")
SELECTION_LABELS = {"best": "best (test-selected)", "last": "last (no test info)"}
PROTOCOLS = {
    "srnn": "8 windows per action (SRNN seeds, the papers' protocol)",
    "random": "256 windows per action (fixed seed)",
}
COLUMNS = [
    "g",
    "experiment",
    "dataset",
    "iterations",
    "seed",
    "run",
    "protocol",
    "checkpoint",
    "metric",
    "action",
    "horizon",
    "value",
    "absent",
    "trained",
]
KEYS = ["g", "protocol", "checkpoint", "metric"]


@dataclass(frozen=True)
class Reference:
    """A published source: key "<paper> <method>", values {action: {ms: value}} (the paper's own
    "average" row included where printed), and what it is where its name does not say."""

    key: str
    published: dict
    about: str | None = None

    @property
    def name(self) -> str:
        paper, method = self.key.split(" ", 1)
        return f"{PAPERS.get(paper, paper)} {method}"


@dataclass
class Judgement:
    """ "reproduces", "misses", "not judged" (the paper prints an average only) or "-" (no
    published values or no target); the reference and why that one; horizons beyond the target
    per checkpoint."""

    status: str
    reference: Reference | None = None
    why: str | None = None
    missed: dict[str, list[int]] | None = None


def printed_gap(ours: float, published: float) -> float:
    """Ours minus published as a reader of the tables computes it: from the printed values."""
    return round(round(ours, 2) - round(published, 2), 2)


def signed(difference: float) -> str:
    """At the printed precision; one that rounds to zero has no sign (+0.00, not -0.00)."""
    return f"{round(difference, 2) + 0.0:+.2f}"


def beyond(ours: dict, published: dict, target: float) -> list[int]:
    """Horizons where ours is further than `target` from published, at the printed precision."""
    return [
        ms
        for ms in HORIZONS
        if ms in published and ms in ours and abs(printed_gap(ours[ms], published[ms])) > target
    ]


def stat(mean: float, std: float, n: int, decimals: int = 2) -> str:
    """mean ± sample std over n seeds; the mean alone for one seed."""
    if mean is None or math.isnan(mean):
        return "-"
    return f"{mean:.{decimals}f}" + (f" ± {std:.{decimals}f}" if n > 1 else "")


def training_files(config: dict, actions: list[str], missing: list[str]) -> dict[str, tuple]:
    """{action: (present, expected)} training files of each action in the run's data copy; {}
    for data without a file list (synthetic)."""
    from src.data.layout import H36M_TRAIN_SUBJECTS, cmu_files, h36m_files

    data = config.get("data", {})
    if data.get("name") == "h36m":
        entries = h36m_files(data.get("train_subjects", H36M_TRAIN_SUBJECTS), actions, "train")
    elif data.get("name") == "cmu":
        entries = cmu_files(actions, "train")
    else:
        return {}
    out: dict[str, tuple] = {}
    for entry in entries:
        present, expected = out.get(entry.action, (0, 0))
        out[entry.action] = (present + (entry.relpath not in set(missing)), expected + 1)
    return out


def missing_of(group: Group) -> list[str]:
    keys = ("missing_files", "train_missing_files")
    return sorted({m for r in group.runs for k in keys for m in r.get(k) or []})


def _euler_table(results: dict) -> dict:
    first = next(iter(next(iter(results.values())).values()))
    return next(t for t in first["tables"] if t["metric"] == "euler")


class Results:
    """The frame of the groups' and baselines' evaluations, and the page's conclusions."""

    def __init__(self, groups: list[Group], baselines: list[dict] = ()):
        self.groups, self.baselines = list(groups), list(baselines)
        self.entries = [*self.groups, *self.baselines]
        self.untrained: dict[str, set[str]] = {}  # dataset -> actions without training files
        for group in self.groups:
            actions = _euler_table(group.runs[0]["results"])["actions"]
            files = training_files(group.runs[0]["config"], actions, missing_of(group))
            untrained = {a for a, (present, _) in files.items() if present == 0}
            self.untrained.setdefault(group.dataset, set()).update(untrained)
        self.frame = pd.DataFrame(self._rows(), columns=COLUMNS)
        self._index = {id(e): k for k, e in enumerate(self.entries)}
        values = self.frame[self.frame.value.notna()]
        sets = values.groupby([*KEYS, "seed"]).action.agg(frozenset).groupby(level=KEYS).nunique()
        if (sets > 1).any():
            raise ReportingError(
                f"{self.label(sets[sets > 1].index[0][0])}: its seeds were evaluated on different "
                "actions; only runs of one configuration on one data copy are averaged"
            )
        euler = values[values.metric == "euler"]
        self.evaluated = {g: list(dict.fromkeys(f.action)) for g, f in euler.groupby("g")}
        self._per_seed, self._averages, self._references = {}, {}, {}
        for judged in (False, True):
            kept = values[values.trained | (not judged)]
            per_seed = kept.groupby([*KEYS, "seed", "horizon"]).value.mean()
            self._per_seed[judged] = per_seed
            self._averages[judged] = per_seed.groupby([*KEYS, "horizon"]).agg(
                ["mean", "std", "count"]
            )

    def _rows(self):
        for g, entry in enumerate(self.entries):
            if isinstance(entry, Group):
                experiment, dataset, iterations = entry.label, entry.dataset, entry.iterations
                runs = [(r["seed"], r["path"], r["results"]) for r in entry.runs]
            else:
                experiment, dataset, iterations = entry["label"], entry["dataset"], 0
                runs = [(0, entry["label"], {"-": entry["results"]})]
            gone = self.untrained.get(dataset, set())
            for seed, run, results in runs:
                for checkpoint, by_protocol in results.items():
                    for protocol, result in by_protocol.items():
                        for t in result["tables"]:
                            for action in t["actions"]:
                                row = t["values"].get(action, {})
                                for ms in t["horizons_ms"]:
                                    yield (
                                        g,
                                        experiment,
                                        dataset,
                                        iterations,
                                        seed,
                                        run,
                                        protocol,
                                        checkpoint,
                                        t["metric"],
                                        action,
                                        int(ms),
                                        row.get(str(ms), math.nan),
                                        t["absent"].get(action, ""),
                                        action not in gone,
                                    )

    def g_of(self, entry) -> int:
        return self._index[id(entry)]

    def label(self, g: int) -> str:
        entry = self.entries[g]
        return entry.label if isinstance(entry, Group) else entry["label"]

    def dataset(self, g: int) -> str:
        entry = self.entries[g]
        return entry.dataset if isinstance(entry, Group) else entry["dataset"]

    def judged_actions(self, g: int) -> list[str]:
        """The evaluated actions this copy has training files of: the judged average's."""
        return [
            a for a in self.evaluated.get(g, []) if a not in self.untrained.get(self.dataset(g), ())
        ]

    def untrained_of(self, g: int) -> list[str]:
        return [a for a in self.evaluated.get(g, []) if a not in self.judged_actions(g)]

    def average(self, g, protocol, checkpoint, metric="euler", judged=False) -> dict:
        """{ms: (mean, std, n)} over the seeds of their averages over the evaluated actions
        (judged: those with training files); {} where there is none."""
        try:
            part = self._averages[judged].loc[(g, protocol, checkpoint, metric)]
        except KeyError:
            return {}
        return {int(ms): (r["mean"], r["std"], int(r["count"])) for ms, r in part.iterrows()}

    def means(self, g, protocol, checkpoint, judged=False) -> dict[int, float]:
        return {ms: v[0] for ms, v in self.average(g, protocol, checkpoint, judged=judged).items()}

    def spread(self, g, protocol, checkpoint, judged=False) -> dict[int, float] | None:
        """The largest minus the smallest of the seeds' Euler averages; None for one seed."""
        try:
            part = self._per_seed[judged].loc[(g, protocol, checkpoint, "euler")]
        except KeyError:
            return None
        by_ms = part.groupby(level="horizon")
        if by_ms.size().max() < 2:
            return None
        return (by_ms.max() - by_ms.min()).to_dict()

    def per_action(self, g: int, metric: str = "euler") -> pd.DataFrame:
        """Per protocol, checkpoint, action and horizon: mean, std, count over the seeds."""
        f = self.frame[(self.frame.g == g) & (self.frame.metric == metric)]
        return f.groupby(["protocol", "checkpoint", "action", "horizon"], sort=False).value.agg(
            ["mean", "std", "count"]
        )

    def references(self, g: int) -> list[Reference]:
        """The published references of an entry, the model's own paper first: the page's own
        entry for Li et al.'s ablations, else what the evaluation printed beside ours, then
        ALSO_PUBLISHED's; on the dataset they were published for only."""
        if g in self._references:
            return self._references[g]
        entry, dataset = self.entries[g], self.dataset(g)
        if isinstance(entry, Group) and entry.run_name in EXPERIMENT_PUBLISHED:
            ref = EXPERIMENT_PUBLISHED[entry.run_name]
        else:
            results = (
                entry.runs[0]["results"] if isinstance(entry, Group) else {"-": entry["results"]}
            )
            label = _euler_table(results).get("published_label") or ""
            ref = dict(zip(("paper", "method"), label.split(" ", 1))) if " " in label else None
        published, key = published_for(ref, dataset)
        refs = [Reference(key, published)] if published else []
        for also in ALSO_PUBLISHED.get((key, dataset), []) if refs else []:
            values, other = published_for(also, dataset)
            refs += [Reference(other, values, also.get("about"))] if values else []
        self._references[g] = refs
        return refs

    def same_set(self, g: int, reference: Reference) -> dict[int, float]:
        return same_set_average(reference.published, self.judged_actions(g), HORIZONS)

    def judge(self, g: int, protocol: str, target: float | None) -> Judgement:
        refs, actions = self.references(g), self.judged_actions(g)
        if not refs or target is None:
            return Judgement("-")
        usable = [r for r in refs if self.same_set(g, r)]
        if not usable:
            return Judgement("not judged", refs[0], "its paper prints an average only")
        chosen = usable[0]
        why = "the only published source" if len(refs) == 1 else "the model's own paper"
        slips = known_slips(chosen.key, actions)
        clean = [r for r in usable[1:] if not known_slips(r.key, actions)]
        if slips and clean:
            chosen = clean[0]
            why = f"{usable[0].name}'s same-set average includes slips of the paper ("
            why += f"{', '.join(slips)})"
        missed = self.missed(g, protocol, chosen, target)
        return Judgement("misses" if any(missed.values()) else "reproduces", chosen, why, missed)

    def missed(self, g: int, protocol: str, reference: Reference, target: float) -> dict:
        """{checkpoint: horizons where its judged average is beyond `target` of the reference's
        same-set average, at the printed precision}."""
        same = self.same_set(g, reference)
        return {s: beyond(self.means(g, protocol, s, True), same, target) for s in SELECTIONS}

    def find(self, label: str, dataset: str) -> int | None:
        """The entry of a baseline (or scored model) by its label and dataset."""
        return next((g for g, e in enumerate(self.entries) if isinstance(e, dict)
                     and (e["label"], e["dataset"]) == (label, dataset)), None)  # fmt: skip

    def validation_means(self, g: int, protocol: str) -> dict[int, dict[int, float]]:
        """{iterations: {ms: mean over seeds}} of the average Euler error at the validations
        every seed made (their TensorBoard curves); {} when a run has none or validated on
        another protocol."""
        runs = self.entries[g].runs
        curves = [r.get("validations") or {} for r in runs]
        if not all(curves) or any(
            r["config"]["data"].get("eval_protocol", "srnn") != protocol for r in runs
        ):
            return {}
        common = sorted(set.intersection(*(set(c) for c in curves)))
        return {
            i: {
                ms: sum(c[i][ms] for c in curves) / len(curves)
                for ms in curves[0][i]
                if all(ms in c[i] for c in curves)
            }
            for i in common
        }

    def diagnosis(self, g: int, protocol: str, judgement: Judgement, checked: str | None) -> str:
        """Where a judged row misses: the actions that carry the largest gap, the seed spread
        against it, and what was compared with the reference code."""
        group, ref, actions = self.entries[g], judgement.reference, self.judged_actions(g)
        same = self.same_set(g, ref)
        gaps = {
            (s, ms): printed_gap(self.means(g, protocol, s, True)[ms], same[ms])
            for s, horizons in judgement.missed.items()
            for ms in horizons
        }
        (selection, ms), gap = max(gaps.items(), key=lambda kv: abs(kv[1]))
        f = self.frame
        cells = (
            f[
                (f.g == g)
                & (f.protocol == protocol)
                & (f.checkpoint == selection)
                & (f.metric == "euler")
                & (f.horizon == ms)
            ]
            .groupby("action")
            .value.mean()
        )
        by_action = {a: cells[a] - ref.published[a][ms] for a in actions}
        top = sorted(by_action.items(), key=lambda kv: -abs(kv[1]))[:3]
        text = (
            f"{group.label} ({group.iterations:,} iterations) misses most at {ms} ms ({selection}"
            f" checkpoint): {signed(gap)} against {ref.name}'s {same[ms]:.2f}, the mean of the "
            f"{len(actions)} actions' gaps, the largest "
            + ", ".join(f"{a} {signed(v)}" for a, v in top)
            + "."
        )
        spread = self.spread(g, protocol, selection, judged=True)
        if spread:
            size = "larger" if spread[ms] > abs(gap) else "smaller"
            text += f" The seed spread there is {spread[ms]:.2f} ({len(group.runs)} seeds), "
            text += f"{size} than the gap."
        else:
            text += " One seed: no spread to weigh the gap against."
        return text + (f" Compared with the reference code: {checked}." if checked else "")
