"""The page's rows: runs of one experiment (run_name), dataset and configuration, differing only
in their seed. Runs of one configuration and seed (a run and a sweep job, a copy, a resumed
run's earlier segments) are one seed: the longest-trained is kept, the others named."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from src.lit.factory import ConfigError
from src.lit.resume import COMPUTES

# Config keys that do not make two runs different experiments: the seed, where files live,
# the device, how often files are written or progress printed, torch.compile (its dropout
# draws other masks than eager, like another seed), and where a resumed run came from.
IGNORED_KEYS = "seed data.seed ckpt_path resume checkpoint_every media_every progress_every_s "
IGNORED_KEYS = set((IGNORED_KEYS + "task_name").split())
IGNORED_PREFIXES = "paths. trainer. compile. hydra. data.data_dir data.archive_dir data.archive "
IGNORED_PREFIXES = tuple((IGNORED_PREFIXES + "data.num_workers data.eval_batch_size").split())
# The budget has a column of its own; data.steps_per_epoch is val_every's copy (conf/data).
BUDGET_KEYS = {"iterations", "val_every", "data.steps_per_epoch"}
# Settings named in words in a label when on (the paper's behaviour is off); any other setting
# that tells two groups of one experiment apart is shown as `leaf=value`. Off, a switch is what
# a run from before it existed did: the same configuration.
SETTING_NAMES = {
    "model.net.reference_eta_offset": "reference-code switches",
    "adversarial.reference_fake_slot": "reference-code switches",
    "data.reference_angle_wrap": "reference-code switches",
}
ABLATIONS = "no_long_term kernel_4x4 kernel_7x2 C5 C5_no_adv C10 C10_no_adv C20 C20_no_adv"
ABLATIONS = [f"li2018_h36m_{n}" for n in ABLATIONS.split()]


def _flatten(config: dict, prefix: str = "") -> dict[str, str]:
    out: dict[str, str] = {}
    for key, value in config.items():
        if isinstance(value, dict):
            out.update(_flatten(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = json.dumps(value)
    return out


def identity(config: dict) -> dict[str, str]:
    """The config less seed, paths, device, logging (trainer keys that change numbers stay)."""
    return {
        k: v
        for k, v in _flatten(config).items()
        if k not in IGNORED_KEYS
        and (not k.startswith(IGNORED_PREFIXES) or k.startswith(COMPUTES))
        and not (k in SETTING_NAMES and v == "false")
    }


def seed_of(run: dict):
    return run.get("seed", run["config"].get("seed"))


@dataclass(eq=False)  # a group is itself: hashed and compared by identity
class Group:
    """settings: what tells it from its experiment's other groups; left_out: runs counted once."""

    label: str
    run_name: str
    dataset: str
    iterations: int
    runs: list[dict] = field(default_factory=list)
    settings: dict = field(default_factory=dict)
    left_out: list[str] = field(default_factory=list)
    ident: dict[str, str] = field(default_factory=dict)
    kind: str = "trained"  # or "baseline", "predictions" (a scored predictions file)

    @property
    def full_label(self) -> str:
        """run_name with every setting that tells it apart: `m (data.future_len=10)`."""
        shown = ", ".join(f"{k}={v}" for k, v in self.settings.items())
        return f"{self.run_name} ({shown})" if shown else self.run_name

    @property
    def ablation(self) -> bool:
        return self.run_name in ABLATIONS


def _keep_one_per_seed(members: list[dict]) -> tuple[list[dict], list[str]]:
    """One run per seed (longest-trained, finished, first given), a line per run left out."""
    rank = lambda r: (r.get("iterations") or 0, bool(r.get("finished", True)))  # noqa: E731
    kept: dict = {}
    for run in members:
        if rank(run) > rank(kept.setdefault(seed_of(run), run)):
            kept[seed_of(run)] = run
    lines, by_folder = [], {m["folder"]: m for m in members if m.get("folder")}
    for seed, run in kept.items():
        segments, before = set(), run  # the folders of the runs a resumed run continues
        while (ckpt := before["config"].get("ckpt_path")) and Path(ckpt).is_absolute():
            folder = str(Path(ckpt).resolve().parent.parent)  # <run>/checkpoints/<file>.ckpt
            if folder == before.get("folder"):  # resumed in its own folder: one segment
                break
            stop = folder in segments or folder not in by_folder
            segments.add(folder)
            if stop:
                break
            before = by_folder[folder]
        earlier = [m for m in members if m.get("folder") in segments]
        earlier.sort(key=lambda m: m.get("iterations") or 0)  # oldest first
        if earlier and "validations" in run:  # each segment's folder logged its own part
            curve = {
                i: e for part in [*earlier, run] for i, e in (part.get("validations") or {}).items()
            }
            run["validations"] = dict(sorted(curve.items()))
        path, n = f"`{run.get('path')}`", lambda r: f"{r.get('iterations'):,}"
        if earlier:  # one line per resumed run: a long run has a segment per session
            parts = ", ".join(f"`{Path(m['folder']).name}` ({n(m)})" for m in earlier)
            lines.append(
                f"seed {seed}: the resumed run {path} ({n(run)} iterations) was kept; it "
                f"continues {len(earlier)} earlier segment(s) of itself: {parts}"
            )
        for other in (m for m in members if seed_of(m) == seed and m is not run):
            if other.get("folder") in segments:
                continue
            if rank(run)[0] != rank(other)[0]:
                why = f"it trained {n(run)} iterations, that one {n(other)}"
            elif rank(run) != rank(other):
                why = "that one has no summary.yaml (unfinished)"
            else:
                why = "given first"
            lines.append(
                f"seed {seed}: `{other.get('path')}` has the same configuration and seed as "
                f"{path}, which was kept ({why}); they count as one seed"
            )
    return [r for r in members if kept[seed_of(r)] is r], lines


def _seed_order(seed) -> tuple:
    """Numbers first, in numeric order, then anything else by its text."""
    number = isinstance(seed, (int, float)) and not isinstance(seed, bool)
    return (0, seed, "") if number else (1, 0, str(seed))


def _short_label(run_name: str, settings: dict) -> str:
    words = [
        SETTING_NAMES.get(k, f"{k.rsplit('.', 1)[-1]}={v}")
        for k, v in settings.items()
        if (v not in (None, False) if k in SETTING_NAMES else v is not None)
    ]
    return ", ".join([run_name, *dict.fromkeys(words)])


def group_runs(runs: list[dict]) -> list[Group]:
    """In the page's order: H3.6M, CMU, other data, ablations last, longest budget first."""
    by_key: dict[tuple, list[dict]] = {}
    for run in runs:
        config = run["config"]
        ident = tuple(sorted(identity(config).items()))
        by_key.setdefault((config.get("run_name"), config["data"]["name"], ident), []).append(run)
    groups, first = [], {}
    for (run_name, dataset, ident), members in by_key.items():
        siblings = [dict(k[2]) for k in by_key if k[:2] == (run_name, dataset)]
        mine = dict(ident)
        value = lambda s, k: s.get(k, "false" if k in SETTING_NAMES else "null")  # noqa: E731
        settings = {
            k: json.loads(value(mine, k))
            for k in sorted({k for s in siblings for k in s} - BUDGET_KEYS)
            if len({value(s, k) for s in siblings}) > 1
        }
        kept, left_out = _keep_one_per_seed(members)
        kept.sort(key=lambda r: _seed_order(seed_of(r)))
        # What the seeds trained (the fewest): runs still training are not their plan's length.
        planned = json.loads(mine.get("iterations", "null"))
        iterations = min(
            (n for n in (planned, *(r.get("iterations") for r in kept)) if n), default=0
        )
        label = _short_label(str(run_name), settings)
        group = Group(label, str(run_name), str(dataset), int(iterations), kept, settings)
        group.left_out, group.ident = left_out, mine
        groups.append(group)
        first.setdefault((group.run_name, group.dataset), len(first))
    for group in groups:  # short labels that collide fall back to the full ones
        key = (group.label, group.dataset, group.iterations)
        if sum((g.label, g.dataset, g.iterations) == key for g in groups) > 1:
            group.label = group.full_label
    rank = {"h36m": 0, "cmu": 1}

    def order(g: Group) -> tuple:
        return (g.ablation, rank.get(g.dataset, 2), first[g.run_name, g.dataset], -g.iterations)

    return sorted(groups, key=order)


def parse_notes(items: list[str], groups: list[Group]) -> dict[str, str]:
    """{label: text} of `LABEL=TEXT` items; the longest label wins, as one may hold '='."""
    names = {g.full_label: g.label for g in groups} | {g.label: g.label for g in groups}
    notes = {}
    for item in items:
        matches = [name for name in names if item.startswith(f"{name}=")]
        if not matches:
            raise ConfigError(
                f"notes: {item!r}: expected EXPERIMENT=TEXT with EXPERIMENT one of the runs' "
                f"experiments: {', '.join(dict.fromkeys(names.values()))}"
            )
        name = max(matches, key=len)
        if not (text := item[len(name) + 1 :].strip()):
            raise ConfigError(f"notes: {item!r}: the text after '=' is empty")
        notes[names[name]] = text
    return notes
