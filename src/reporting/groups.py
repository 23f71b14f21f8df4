"""The page's rows: the runs of one experiment (run_name) on one dataset with one budget (the
iterations planned), differing in their seed. A variant of an experiment (the reference-code
switches, another C) is trained under a run_name of its own (conf/experiment/); runs of one
run_name that differ in what they train (SECTIONS: a sweep over model.net.hidden, say) are rows
of their own, labelled by what tells them apart (`residual_mlp_synthetic, hidden=16`). Runs of
one seed (a run and a sweep job, a copy, a resumed run's segments) count once: the longest
trained is kept, the others named."""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass, field

import pandas as pd

from src.config import ConfigError

# What a model is and how it trains (not where files live, the device, the logging).
SECTIONS = ("model", "adversarial", "sampling", "trainer.precision")
ABLATIONS = "no_long_term kernel_4x4 kernel_7x2 C5 C5_no_adv C10 C10_no_adv C20 C20_no_adv"
ABLATIONS = [f"li2018_h36m_{n}" for n in ABLATIONS.split()]


def settings(config: dict, sections=SECTIONS) -> dict[str, str]:
    """{dotted key: value as JSON} of the config's `sections` (dotted too); none of a null one."""
    flat = pd.json_normalize(config, sep=".").to_dict("records")[0] if config else {}
    kept = lambda k, v: any(k.startswith(f"{s}.") or (k == s and v is not None) for s in sections)  # noqa: E731
    return {k: json.dumps(v) for k, v in flat.items() if kept(k, v)}


def seed_of(run: dict):
    return run.get("seed", run["config"].get("seed"))


@dataclass(eq=False)  # a group is itself: hashed and compared by identity
class Group:
    """left_out: a line per run counted once with a kept one."""

    label: str
    run_name: str
    dataset: str
    iterations: int
    runs: list[dict] = field(default_factory=list)
    left_out: list[str] = field(default_factory=list)
    kind: str = "trained"  # or "baseline", "predictions" (a scored predictions file)

    @property
    def ablation(self) -> bool:
        return self.run_name in ABLATIONS


def _one_per_seed(members: list[dict]) -> tuple[list[dict], list[str]]:
    """The longest-trained (then finished, then first given) run of each seed, and a line per
    seed that had more than one. A resume continues in its run's folder, curve included, so
    nothing is joined: a record keeps the curve of segments joined before."""
    rank = lambda r: (r.get("iterations") or 0, bool(r.get("finished", True)))  # noqa: E731
    kept: dict = {}
    for run in members:
        if rank(run) > rank(kept.setdefault(seed_of(run), run)):
            kept[seed_of(run)] = run
    lines, n = [], lambda r: f"{r.get('iterations') or 0:,}"
    for seed, run in kept.items():
        if not (others := [m for m in members if seed_of(m) == seed and m is not run]):
            continue
        shown = ", ".join(f"`{m.get('path')}` ({n(m)})" for m in others)
        lines.append(f"seed {seed}: `{run.get('path')}` ({n(run)} iterations) kept; {shown}")
    return [r for r in members if kept[seed_of(r)] is r], lines


def _seed_order(seed) -> tuple:
    """Numbers first, in numeric order, then anything else by its text."""
    number = isinstance(seed, (int, float)) and not isinstance(seed, bool)
    return (0, seed, "") if number else (1, 0, str(seed))


def group_runs(runs: list[dict]) -> list[Group]:
    """In the page's order: H3.6M, CMU, other data, ablations last, longest budget first."""
    by_key: dict[tuple, list[dict]] = {}
    for run in runs:
        config = run["config"]
        key = (str(config.get("run_name")), str(config["data"]["name"]), config.get("iterations"))
        by_key.setdefault(key, []).append(run)
    groups, first = [], {}
    variants: dict[tuple, list[dict]] = {}
    for (run_name, dataset, planned), members in by_key.items():
        found = [settings(r["config"]) for r in members]
        differ = sorted(
            {k for a in found for b in found for k in a.keys() & b.keys() if a[k] != b[k]}
        )
        # A run that predates a switch ran as its most common setting does (the default).
        usual = {k: Counter(s[k] for s in found if k in s).most_common(1)[0][0] for k in differ}
        for run, these in zip(members, found, strict=True):
            told = [f"{k.rpartition('.')[2]}={json.loads(these.get(k, usual[k]))}" for k in differ]
            label = ", ".join([run_name, *told])
            variants.setdefault((label, run_name, dataset, planned), []).append(run)
    for (label, run_name, dataset, planned), members in variants.items():
        kept, left_out = _one_per_seed(members)
        kept.sort(key=lambda r: _seed_order(seed_of(r)))
        # What the seeds trained (the fewest): runs still training are not their plan's length.
        iterations = min(
            (n for n in (planned, *(r.get("iterations") for r in kept)) if n), default=0
        )
        group = Group(label, run_name, dataset, int(iterations), kept, left_out)
        groups.append(group)
        first.setdefault((run_name, dataset), len(first))
    rank = {"h36m": 0, "cmu": 1}

    def order(g: Group) -> tuple:
        return (g.ablation, rank.get(g.dataset, 2), first[g.run_name, g.dataset], -g.iterations)

    return sorted(groups, key=order)


def parse_notes(items: list[str], groups: list[Group]) -> dict[str, str]:
    """{label: text} of `LABEL=TEXT` items; the longest label wins, as one may hold '='."""
    names = list(dict.fromkeys(g.label for g in groups))
    notes = {}
    for item in items:
        if not (matches := [name for name in names if item.startswith(f"{name}=")]):
            raise ConfigError(
                f"notes: {item!r}: expected EXPERIMENT=TEXT with EXPERIMENT one of the runs' "
                f"experiments: {', '.join(names)}"
            )
        name = max(matches, key=len)
        if not (text := item[len(name) + 1 :].strip()):
            raise ConfigError(f"notes: {item!r}: the text after '=' is empty")
        notes[name] = text
    return notes
