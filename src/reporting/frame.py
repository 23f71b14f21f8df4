"""Every evaluation as one long table (`Results.frame`: a row per run, protocol, checkpoint, metric,
action, horizon; value NaN where absent, trained False without training files), and what the page
concludes from it: a cell is the mean ± std (n - 1) over the seeds of each seed's average over the
actions; a group is judged against its own paper's same-set average, over the actions with
training files, the paper's slips left out (known ones, and every published zero-velocity cell
that the protocol's deterministic zero-velocity does not give).
"""

from __future__ import annotations

from typing import NamedTuple

import pandas as pd

from src.reporting.groups import Group
from src.reporting.published import PAPERS, REFERENCES, ReportingError, known_slips, published_for
from src.reporting.tables import same_set_average

HORIZONS = (80, 160, 320, 400, 560, 1000)
SELECTIONS = ("best", "last")
SELECTION_LABELS = {"best": "best (test-selected)", "last": "last (no test info)"}
PROTOCOLS = {
    "srnn": "8 windows per action (SRNN seeds, the papers' protocol)",
    "random": "256 windows per action (fixed seed)",
}
COLUMNS = ["g", "experiment", "dataset", "iterations", "seed", "run", "protocol", "checkpoint"]
COLUMNS += ["metric", "action", "horizon", "value", "absent", "trained"]
KEYS = ["g", "protocol", "checkpoint", "metric"]
# A printed value is rounded to 2 decimals: a difference beyond half of its last digit is not
# rounding. Zero-velocity is deterministic, so such a published cell is a slip of the paper.
ROUNDING = 0.005
ZERO = "zero_velocity"


class Reference(NamedTuple):
    """key "<paper> <method>", {action: {ms: value}} with the paper's "average" where printed."""

    key: str
    published: dict
    about: str | None = None

    @property
    def name(self) -> str:
        paper, method = self.key.split(" ", 1)
        return f"{PAPERS.get(paper, paper)} {method}"


class Judgement(NamedTuple):
    """A status ("reproduces", "misses", "not judged", "-"), the reference, why, horizons missed."""

    status: str
    reference: Reference | None = None
    why: str | None = None
    missed: dict | None = None


def printed_gap(ours: float, published: float) -> float:
    """Ours minus published as a reader of the tables computes it: from the printed values."""
    return round(round(ours, 2) - round(published, 2), 2)


def signed(difference: float) -> str:
    """At the printed precision; one that rounds to zero has no sign (+0.00, not -0.00)."""
    return f"{round(difference, 2) + 0.0:+.2f}"


def ms_list(horizons: list[int]) -> str:
    return ", ".join(map(str, horizons)) + " ms"


def stat(mean: float, std: float, n: int, decimals: int = 2) -> str:
    return f"{mean:.{decimals}f}" + (f" ± {std:.{decimals}f}" if n > 1 else "")


def long_values(published: dict) -> pd.DataFrame:
    """{action: {ms: value}} as rows: action, ms, published."""
    cells = [(a, ms, v) for a, by_ms in published.items() for ms, v in by_ms.items()]
    return pd.DataFrame(cells, columns=["action", "ms", "published"])


def training_files(group: Group, actions: list[str]) -> dict[str, tuple[int, int]]:
    """{action: (present, expected)} training files of the group's data copy."""
    from src.data.layout import H36M_TRAIN_SUBJECTS, cmu_files, h36m_files

    data = group.runs[0]["config"].get("data", {})
    if data.get("name") == "h36m":
        entries = h36m_files(data.get("train_subjects", H36M_TRAIN_SUBJECTS), actions)
    else:
        entries = cmu_files(actions, "train") if data.get("name") == "cmu" else []
    keys = ("missing_files", "train_missing_files")
    missing = {m for r in group.runs for k in keys for m in r.get(k) or []}
    files = pd.DataFrame([(e.action, e.relpath not in missing) for e in entries], columns=[0, 1])
    return {a: (int(p.sum()), len(p)) for a, p in files.groupby(0, sort=False)[1]}


class Results:
    """The long table of the groups' and baselines' evaluations, and the page's conclusions."""

    def __init__(self, groups: list[Group], baselines: list[dict] = ()):
        self.groups = list(groups)
        self.baselines = [  # a baseline or a scored model: one run without checkpoints
            Group(b["label"], b["label"], b["dataset"], 0, [r], kind=b.get("kind", "baseline"))
            for b in baselines
            for r in [b | {"seed": 0, "path": b["label"]}]
        ]
        self.entries = [*self.groups, *self.baselines]
        self._g = {e: k for k, e in enumerate(self.entries)}
        self.files = {g: training_files(g, _actions(g)) for g in self.groups}
        self.untrained: dict[str, set[str]] = {}  # dataset -> actions without training files
        for g, files in self.files.items():
            gone = {a for a, (present, _) in files.items() if present == 0}
            self.untrained.setdefault(g.dataset, set()).update(gone)
        self.frame = pd.concat(
            [self._rows(g, e) for g, e in enumerate(self.entries)]
            or [pd.DataFrame(columns=COLUMNS)],
            ignore_index=True,
        )[COLUMNS]
        values = self.frame[self.frame.value.notna()]
        sets = values.groupby([*KEYS, "seed"]).action.agg(frozenset).groupby(level=KEYS).nunique()
        if (sets > 1).any():
            raise ReportingError(
                f"{self.entries[sets[sets > 1].index[0][0]].label}: its seeds were evaluated on "
                "different actions; only runs of one configuration on one data copy are averaged"
            )
        self.values = values
        self.evaluated = values[values.metric == "euler"].groupby("g").action.unique().map(list)
        self.refs = {e: self._references(e) for e in self.entries}  # the model's own paper first
        self.zero_cells = self._zero_velocity_cells()
        self.slip_cells = self.zero_cells[self.zero_cells.slip]
        self.slips: dict[str, dict[str, str]] = {}  # reference key -> {action: why}
        for e in self.entries:
            for ref in self.refs[e]:
                found = known_slips(ref.key, self.actions(e, judged=False))
                self.slips.setdefault(ref.key, {}).update(found)
        for key, action, why in self.slip_cells[["key", "action", "why"]].itertuples(index=False):
            self.slips.setdefault(key, {}).setdefault(action, why)

    def _rows(self, g: int, group: Group) -> pd.DataFrame:
        gone = self.untrained.get(group.dataset, set())
        frame = pd.concat([r["rows"].assign(seed=r["seed"], run=r["path"]) for r in group.runs])
        keys = {"g": g, "experiment": group.label, "dataset": group.dataset}
        frame = frame.assign(**keys, iterations=group.iterations)
        return frame.assign(trained=~frame.action.isin(gone))

    def actions(self, group: Group, judged: bool = True) -> list[str]:
        """The evaluated actions (judged: those this copy has training files of)."""
        gone = self.untrained.get(group.dataset, set()) if judged else set()
        return [a for a in self.evaluated.get(self._g[group], []) if a not in gone]

    def untrained_actions(self, group: Group) -> list[str]:
        """The evaluated actions this copy has no training file of (not judged)."""
        gone = self.untrained.get(group.dataset, set())
        return [a for a in self.actions(group, judged=False) if a in gone]

    def seed_means(self, entry, protocol, checkpoint, metric="euler", judged=False, actions=None):
        """Each seed's average over the (judged) actions, or over exactly `actions` (empty unless
        every one was evaluated), indexed by seed and horizon."""
        f = self.values
        f = f[(f.g == self._g[entry]) & (f.protocol == protocol) & (f.checkpoint == checkpoint)]
        f = f[(f.metric == metric) & (f.trained | (not judged))]
        if actions is not None:
            f = f[f.action.isin(actions)]
            f = f if len(actions) and set(f.action) == set(actions) else f.iloc[:0]
        return f.groupby(["seed", "horizon"]).value.mean().groupby(level="horizon")

    def average(self, group, protocol, checkpoint, metric="euler", judged=False) -> dict:
        """{ms: (mean, std, n)} over the seeds; {} where there is none."""
        by_ms = self.seed_means(group, protocol, checkpoint, metric, judged)
        return {int(ms): (v.mean(), v.std(), len(v)) for ms, v in by_ms}

    def means(self, group, protocol, checkpoint, judged=False, actions=None) -> dict[int, float]:
        """{ms: the mean over the seeds}; over `actions`: {} unless every one was evaluated."""
        by_ms = self.seed_means(group, protocol, checkpoint, judged=judged, actions=actions)
        return {int(ms): v for ms, v in by_ms.mean().items()}

    def spread(self, group, protocol, checkpoint, judged=False) -> dict[int, float] | None:
        """The largest minus the smallest of the seeds' Euler averages; None for one seed."""
        by_ms = self.seed_means(group, protocol, checkpoint, judged=judged)
        if by_ms.ngroups and by_ms.size().max() > 1:
            return (by_ms.max() - by_ms.min()).to_dict()

    def _references(self, group: Group) -> list[Reference]:
        """Its published references on its dataset, the model's own paper first."""
        ref = REFERENCES["experiment_published"].get(group.run_name, "-")
        if ref == "-":  # the one its evaluation printed beside ours
            run = group.runs[0]
            ref = (
                run["config"].get("model", {}).get("published")
                if "config" in run
                else run["published"]
            )
        published, key = published_for(ref, group.dataset)
        refs = [Reference(key, published)] if published else []
        for also in REFERENCES["also_published"].get(f"{key} {group.dataset}", []):
            values, other = published_for(also, group.dataset)
            refs += [Reference(other, values, also.get("about"))] if values else []
        return refs

    def _zero_velocity_cells(self) -> pd.DataFrame:
        """Each published zero-velocity cell of an action evaluated here on the papers' windows
        (SRNN seeds) beside ours: key, dataset, action, ms, published, ours, slip (beyond
        rounding), why."""
        f = self.values[(self.values.protocol == "srnn") & (self.values.metric == "euler")]
        f = f.rename(columns={"horizon": "ms", "value": "ours"})
        cells = [
            f[f.g == self._g[zero]].merge(long_values(ref.published), on=["action", "ms"])
            .assign(key=ref.key)
            for zero in self.baselines if zero.label == ZERO
            for ref in self.refs[zero] if ref.key.endswith(f" {ZERO}")
        ]  # fmt: skip
        empty = long_values({}).assign(ours=0.0, key="", dataset="").astype({"ms": int})
        c = pd.concat([empty, *cells], ignore_index=True)
        c["why"] = [f"published {p:.2f} at {ms} ms, the protocol gives {o:.3f}"
                    for p, ms, o in zip(c.published, c.ms, c.ours, strict=True)]  # fmt: skip
        c["slip"] = (c.ours - c.published).abs() > ROUNDING
        return c[["key", "dataset", "action", "ms", "published", "ours", "slip", "why"]]

    def slips_in(self, reference: Reference, actions: list[str]) -> dict[str, str]:
        """{action: why} of the `actions` whose published values under `reference` are slips."""
        slips = self.slips.get(reference.key, {})
        return {a: slips[a] for a in actions if a in slips}

    def clean_actions(self, group: Group, reference: Reference, judged=True) -> list[str]:
        """The (judged) evaluated actions less the reference's slips: its same-set actions."""
        actions = self.actions(group, judged)
        return [a for a in actions if a not in self.slips_in(reference, actions)]

    def same_set(self, group: Group, reference: Reference, judged=True) -> dict[int, float]:
        """The reference's average over the (judged) evaluated actions, its slips left out."""
        actions = self.clean_actions(group, reference, judged)
        return same_set_average(reference.published, actions, HORIZONS)

    def zero(self, dataset: str) -> Group | None:
        """The zero-velocity baseline on `dataset`: the yardstick."""
        return next((b for b in self.baselines if (b.label, b.dataset) == (ZERO, dataset)), None)

    def no_better_than_zero(self, group: Group, protocol: str) -> dict[str, list[int]]:
        """{checkpoint: horizons where, as printed, ours is not below zero-velocity's average over
        the same judged actions}; {} without a zero-velocity evaluation of them."""
        yardstick, actions = self.zero(group.dataset), self.actions(group)
        if yardstick is None or not (zero := self.means(yardstick, protocol, "-", actions=actions)):
            return {}
        out = {}
        for s in SELECTIONS:
            ours = self.means(group, protocol, s, actions=actions)
            out[s] = [ms for ms in HORIZONS if ms in ours and ms in zero and
                      round(ours[ms], 2) >= round(zero[ms], 2)]  # fmt: skip
        return out

    def gaps(self, group: Group, reference: Reference, protocol: str) -> pd.DataFrame:
        """At each horizon of the reference's same-set average (`same`): ours over its actions
        (best, last; slips left out on both sides), ours minus it as printed ("best gap", ...)."""
        actions = self.clean_actions(group, reference)
        ours = {s: self.means(group, protocol, s, actions=actions) for s in SELECTIONS}
        t = pd.DataFrame({"same": self.same_set(group, reference), **ours}).dropna(subset="same")
        for s in SELECTIONS:
            t[f"{s} gap"] = [printed_gap(o, p) for o, p in zip(t[s], t.same, strict=True)]
        return t

    def missed(self, group: Group, protocol: str, reference: Reference, target: float) -> dict:
        """{checkpoint: horizons where it is beyond `target` of the same-set average as printed}."""
        t = self.gaps(group, reference, protocol)
        return {s: [int(ms) for ms in t.index[t[f"{s} gap"].abs() > target]] for s in SELECTIONS}

    def reference(self, group: Group) -> tuple[Reference | None, str]:
        """The reference a group is judged against (its own paper's, unless that one has no
        same-set average), and why that one."""
        refs = self.refs[group]
        if not (usable := [r for r in refs if self.same_set(group, r)]):
            return None, "its paper prints an average only"
        why = "the only published source" if len(refs) == 1 else "the model's own paper"
        if usable[0] is not refs[0]:
            why = f"{refs[0].name} has no same-set average"
        actions = self.actions(group)
        if slips := self.slips_in(usable[0], actions):
            kept = len(actions) - len(slips)
            why += (
                f", over {kept} of the {len(actions)} actions: {', '.join(slips)} left out as "
                "slips of the paper"
            )
        return usable[0], why

    def judge(self, group: Group, protocol: str, target: float | None) -> Judgement:
        if not (refs := self.refs[group]) or target is None:
            return Judgement("-")
        chosen, why = self.reference(group)
        if chosen is None:
            return Judgement("not judged", refs[0], why)
        missed = self.missed(group, protocol, chosen, target)
        return Judgement("misses" if any(missed.values()) else "reproduces", chosen, why, missed)

    def validation_means(self, group: Group, protocol: str) -> dict[int, dict[int, float]]:
        """{iterations: {ms: mean over the seeds}} at the validations every seed made, else {}."""
        curves = [pd.DataFrame(r.get("validations") or {}).T.stack() for r in group.runs]
        protocols = {r["config"]["data"].get("eval_protocol", "srnn") for r in group.runs}
        if not all(len(c) for c in curves) or protocols != {protocol}:
            return {}
        means = pd.concat(curves, axis=1).dropna().mean(axis=1).sort_index()
        return {int(i): {int(ms): v for (_, ms), v in e.items()} for i, e in means.groupby(level=0)}

    def diagnosis(self, group: Group, protocol: str, judgement: Judgement, checked=None) -> str:
        """Where a judged row misses most, the actions that carry it, the seed spread beside it."""
        ref, t = judgement.reference, self.gaps(group, judgement.reference, protocol)
        gaps = {(s, ms): t.at[ms, f"{s} gap"] for s, hs in judgement.missed.items() for ms in hs}
        (selection, ms), gap = max(gaps.items(), key=lambda kv: abs(kv[1]))
        f = self.frame
        f = f[(f.g == self._g[group]) & (f.protocol == protocol) & (f.metric == "euler")]
        cells = f[(f.checkpoint == selection) & (f.horizon == ms)].groupby("action").value.mean()
        actions = self.clean_actions(group, ref)
        top = [(a, cells[a] - ref.published[a][ms]) for a in actions]
        top = ", ".join(f"{a} {signed(v)}" for a, v in sorted(top, key=lambda kv: -abs(kv[1]))[:3])
        text = (
            f"{group.label} ({group.iterations:,} iterations) misses most at {ms} ms ({selection} "
            f"checkpoint): {signed(gap)} against {ref.name}'s {t.at[ms, 'same']:.2f}, the mean of "
            f"the {len(actions)} actions' gaps, the largest {top}."
        )
        if (spread := self.spread(group, protocol, selection, judged=True)) is not None:
            size = "larger" if spread[ms] > abs(gap) else "smaller"
            text += f" The seed spread there is {spread[ms]:.2f} ({len(group.runs)} seeds), "
            text += f"{size} than the gap."
        else:
            text += " One seed: no spread to weigh the gap against."
        return text + (f" {checked}." if checked else "")


def _actions(group: Group) -> list[str]:
    """The first run's actions, absent ones too."""
    rows = group.runs[0]["rows"]
    return list(dict.fromkeys(rows.action[rows.metric == "euler"]))
