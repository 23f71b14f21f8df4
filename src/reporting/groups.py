"""Grouping run records into experiments (src.report).

Runs are grouped by experiment (run_name), dataset and configuration: runs of one group differ
only in their seed. Two runs with the same configuration and the same seed (a run and a sweep
job of the same settings, a copy, the earlier segments of a resumed run) are one seed: one is
kept, and the group says which, and whether each other is a copy or a segment. Also the
`--note` texts, which name a group by its label.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from src.lit.resume import COMPUTES

# Config keys that do not make two runs different experiments: the seed, where files live,
# the device, how often files are written or progress printed, and torch.compile (whose
# dropout draws other masks than eager, of the same distribution, like another seed).
# A resumed run is the run it continues: `resume` and `ckpt_path` name where it came from.
IGNORED_KEYS = (
    "seed",
    "data.seed",
    "ckpt_path",
    "resume",
    "checkpoint_every",
    "media_every",
    "progress_every_s",
    "task_name",
)
IGNORED_PREFIXES = (
    "paths.",
    "trainer.",
    "compile.",
    "hydra.",
    "data.data_dir",
    "data.archive_dir",
    "data.archive",
    "data.num_workers",
    "data.eval_batch_size",
)
# Settings named in words in a row's label when on (the paper's behaviour is off); any other
# setting that tells two groups of one experiment apart is shown as `leaf=value`.
SETTING_NAMES = {
    "model.net.reference_eta_offset": "reference-code switches",
    "adversarial.reference_fake_slot": "reference-code switches",
}


def _flatten(config: dict, prefix: str = "") -> dict[str, str]:
    out: dict[str, str] = {}
    for key, value in config.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(_flatten(value, f"{name}."))
        else:
            out[name] = json.dumps(value)
    return out


def identity(config: dict) -> dict[str, str]:
    """What makes a run the experiment it is: its config less seed, paths, device, logging."""
    return {
        k: v
        for k, v in _flatten(config).items()
        if k not in IGNORED_KEYS
        # Trainer keys that change the numbers make another setting, not another seed.
        and (not k.startswith(IGNORED_PREFIXES) or k.startswith(COMPUTES))
    }


@dataclass
class Group:
    """Runs of one experiment on one dataset that differ only in their seed.

    label: short, for tables (`li2018_h36m, reference-code switches`); settings: the config
    values that tell this group apart from the other groups of its experiment (the footnote
    of its label); left_out: runs identical to a kept one (same configuration and seed: a copy,
    or an earlier segment of a resumed run)."""

    label: str
    run_name: str
    dataset: str
    runs: list[dict] = field(default_factory=list)
    settings: dict[str, object] = field(default_factory=dict)
    left_out: list[str] = field(default_factory=list)
    ident: dict[str, str] = field(default_factory=dict)

    @property
    def full_label(self) -> str:
        """run_name with every setting that tells it apart: `m (data.future_len=10)`."""
        if not self.settings:
            return self.run_name
        return f"{self.run_name} (" + ", ".join(f"{k}={v}" for k, v in self.settings.items()) + ")"


def _short_label(run_name: str, settings: dict[str, object]) -> str:
    words: list[str] = []
    for key, value in settings.items():
        if value is None:  # the setting is not in this group's config at all
            word = None
        elif key in SETTING_NAMES:
            word = SETTING_NAMES[key] if value is not False else None
        else:
            word = f"{key.rsplit('.', 1)[-1]}={value}"
        if word and word not in words:
            words.append(word)
    return ", ".join([run_name, *words])


def _segments_before(run: dict, members: list[dict]) -> set[str]:
    """The folders of the runs a resumed run continues: the one its ckpt_path lies in, the
    one that one resumed from, and so on (src.train writes ckpt_path as given, absolute in
    every resume the project's scripts make; a relative one cannot be placed and is not
    followed)."""
    by_folder = {m["folder"]: m for m in members if m.get("folder")}
    found: set[str] = set()
    while (ckpt := run["config"].get("ckpt_path")) and Path(ckpt).is_absolute():
        folder = str(Path(ckpt).resolve().parent.parent)  # <run>/checkpoints/<file>.ckpt
        if folder in found:
            break
        found.add(folder)
        if folder not in by_folder:
            break
        run = by_folder[folder]
    return found


def _keep_one_per_seed(members: list[dict]) -> tuple[list[dict], list[str]]:
    """One run per seed: of identical runs, the one that trained longest, then a finished one,
    then the first given; and a line per run left out saying which was kept, and whether it is
    an earlier segment of the kept run (resumed from its checkpoint) or a copy."""
    kept: dict[object, dict] = {}
    for run in members:
        seed = run.get("seed", run["config"].get("seed"))
        kept.setdefault(seed, run)
        other = kept[seed]
        if other is not run and _rank(run) > _rank(other):
            kept[seed] = run
    segments = {seed: _segments_before(run, members) for seed, run in kept.items()}
    for seed, run in kept.items():
        # The kept run's validation curve over every segment: each folder logged its own part.
        earlier = [m for m in members if m.get("folder") in segments[seed]]
        if earlier and "validations" in run:
            curve: dict[int, dict[int, float]] = {}
            for part in [*earlier, run]:
                curve.update(part.get("validations") or {})
            run["validations"] = dict(sorted(curve.items()))
    lines = []
    for run in members:
        seed = run.get("seed", run["config"].get("seed"))
        chosen = kept[seed]
        if chosen is run:
            continue
        if run.get("folder") in segments[seed]:
            lines.append(
                f"seed {seed}: `{run.get('path')}` ({run.get('iterations'):,} iterations) is an "
                f"earlier segment of the resumed run `{chosen.get('path')}` "
                f"({chosen.get('iterations'):,}), which was kept"
            )
            continue
        if _rank(chosen)[0] != _rank(run)[0]:
            why = f"it trained {chosen.get('iterations'):,} iterations, that one "
            why += f"{run.get('iterations'):,}"
        elif _rank(chosen)[1] != _rank(run)[1]:
            why = "that one has no summary.yaml (unfinished)"
        else:
            why = "given first"
        lines.append(
            f"seed {seed}: `{run.get('path')}` has the same configuration and seed as "
            f"`{chosen.get('path')}`, which was kept ({why}); they count as one seed"
        )
    return [r for r in members if kept[r.get("seed", r["config"].get("seed"))] is r], lines


def _seed_order(seed: object) -> tuple[int, float, str]:
    """Numbers first, in numeric order, then anything else by its text."""
    if isinstance(seed, (int, float)) and not isinstance(seed, bool):
        return (0, float(seed), "")
    return (1, 0.0, str(seed))


def _rank(run: dict) -> tuple[int, bool]:
    return (run.get("iterations") or 0, bool(run.get("finished", True)))


def group_runs(runs: list[dict]) -> list[Group]:
    """Group run records ({"config": ..., ...}) by run_name, dataset and configuration, in order
    of first appearance. Runs sharing a run_name but differing in another setting (a budget, a
    switch) are separate groups, labelled with the settings that tell them apart; identical
    runs (same configuration and seed) count once."""
    by_key: dict[tuple, list[dict]] = {}
    for run in runs:
        config = run["config"]
        ident = identity(config)
        key = (config.get("run_name"), config["data"]["name"], tuple(sorted(ident.items())))
        by_key.setdefault(key, []).append(run)
    groups = []
    for (run_name, dataset, ident), members in by_key.items():
        siblings = [dict(k[2]) for k in by_key if k[:2] == (run_name, dataset)]
        settings: dict[str, object] = {}
        if len(siblings) > 1:
            mine = dict(ident)
            keys = sorted(
                k
                for k in {k for s in siblings for k in s}
                if len({s.get(k, "null") for s in siblings}) > 1
            )
            settings = {k: json.loads(mine.get(k, "null")) for k in keys}
        kept, left_out = _keep_one_per_seed(members)
        # In seed order, whichever order the runs were found or recorded in.
        kept.sort(key=lambda r: _seed_order(r.get("seed", r["config"].get("seed"))))
        group = Group("", str(run_name), str(dataset), kept, settings, left_out, dict(ident))
        group.label = _short_label(group.run_name, settings)
        groups.append(group)
    # Short labels that collide (two settings named alike) fall back to the full ones.
    for group in groups:
        if sum(g.label == group.label and g.dataset == group.dataset for g in groups) > 1:
            group.label = group.full_label
    return groups


def parse_notes(items: list[str], labels) -> dict[str, str]:
    """{label: text} from `--note LABEL=TEXT` items. `labels` lists the accepted labels, or maps
    each accepted name (a group's short or full label) to the label it stands for. A label may
    itself hold '=' ("martinez2017_res_sup (data.future_len=10)"), so the longest label that the
    item starts with wins."""
    names = labels if isinstance(labels, dict) else {label: label for label in labels}
    notes = {}
    for item in items:
        matches = [name for name in names if item.startswith(f"{name}=")]
        if not matches:
            raise SystemExit(
                f"error: --note {item!r}: expected EXPERIMENT=TEXT with EXPERIMENT one of the "
                f"runs' experiments: {', '.join(dict.fromkeys(names.values()))}"
            )
        name = max(matches, key=len)
        text = item[len(name) + 1 :].strip()
        if not text:
            raise SystemExit(f"error: --note {item!r}: the text after '=' is empty")
        notes[names[name]] = text
    return notes


def note_names(groups: list[Group]) -> dict[str, str]:
    """Every name a --note may use for a group (short or full label) -> its label."""
    names = {g.full_label: g.label for g in groups}
    names.update({g.label: g.label for g in groups})
    return names
