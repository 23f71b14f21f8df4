"""A resume continues a run, not a config: `restore_run` puts the command line's overrides on
top of the run's own `config.yaml` (beside its `checkpoints/`). Where files live is this
command's (FROM_HERE); the length, logging and the Trainer's settings may change (FREE); an
override of anything else is refused naming each key with both values."""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import DictConfig, ListConfig, OmegaConf

from src.config import ConfigError, check
from src.lit.checkpoints import LAST, CheckpointError, read_checkpoint
from src.lit.factory import build_parts

# "hydra": in a config composed in-process (and so in the config.yaml of such a run).
FROM_HERE = ("hydra", "paths", "ckpt_path", "resume", "trainer.default_root_dir",
             "data.data_dir", "data.archive_dir", "data.archive")  # fmt: skip
# The Trainer's device settings are the user's to adapt to the machine. Not `compile`:
# compiled dropout draws other masks than eager, so the resume would not be exact.
FREE = ("iterations", "run_name", "task_name", "checkpoint_every", "media_every",
        "progress_every_s", "trainer", "data.num_workers")  # fmt: skip
# ... except these, which change the numbers (bf16-mixed autocast): a resume keeps the run's.
COMPUTES = ("trainer.precision",)
_ABSENT = object()


def _under(key: str, prefixes: tuple[str, ...]) -> bool:
    return any(key == p or key.startswith(p + ".") for p in prefixes)


def _free(key: str) -> bool:
    return _under(key, FREE) and not _under(key, COMPUTES)


@dataclass
class Resume:
    checkpoint: Path
    run_dir: Path
    applied: list[str]  # the command line's overrides, applied on top of the run's settings
    from_checkpoint: bool  # no config.yaml beside it: sections stored in the checkpoint
    run_choices: dict[str, str] | None  # the run's config-group options, when recorded

    @property
    def in_place(self) -> bool:
        """From the command line, the run continues in its own folder (it has one)."""
        return not self.from_checkpoint


def checkpoint_to_resume(cfg: DictConfig) -> Path | None:
    """The checkpoint of `resume=<run folder>` (its checkpoints/last.ckpt) or `ckpt_path=`."""
    resume, ckpt = cfg.get("resume"), cfg.get("ckpt_path")
    if not resume:
        return Path(str(ckpt)) if ckpt else None
    target = Path(str(resume))
    if target.is_dir():  # the run folder, or its checkpoints/ (named, too, by a user)
        target = target / LAST if (target / LAST).is_file() else target / "checkpoints" / LAST
    if ckpt and Path(str(ckpt)) != target:
        raise ConfigError(
            f"resume={resume} and ckpt_path={ckpt} name different checkpoints; give only one."
        )
    return target


def _raw(tree: Any, key: str) -> Any:
    """The value at a dotted key of a plain container, or _ABSENT."""
    for part in key.split("."):
        if not isinstance(tree, dict) or part not in tree:
            return _ABSENT
        tree = tree[part]
    return tree


def _put(cfg: DictConfig, key: str, value: Any) -> None:
    """Set a dotted key (unresolved); remove it for _ABSENT."""
    if value is not _ABSENT:
        OmegaConf.update(cfg, key, value, merge=False, force_add=True)
        return
    parent, _, leaf = key.rpartition(".")
    node = OmegaConf.select(cfg, parent) if parent else cfg
    if isinstance(node, DictConfig) and leaf in node:
        del node[leaf]


def _leaves(cfg: DictConfig, key: str) -> dict[str, Any]:
    """The resolved leaves under a dotted key ("": all), by key, but the FROM_HERE and FREE
    ones (which may point at Hydra state not set up yet); _ABSENT for a key not there."""
    if _under(key, FROM_HERE) or _free(key):
        return {}
    node = OmegaConf.select(cfg, key, default=_ABSENT) if key else cfg
    if isinstance(node, DictConfig) and len(node):
        return {k: v for sub in node for k, v in _leaves(cfg, f"{key}.{sub}".lstrip(".")).items()}
    if isinstance(node, (DictConfig, ListConfig)):
        node = OmegaConf.to_container(node, resolve=True)
    return {key: "absent" if node is _ABSENT else node}


def restore_run(
    cfg: DictConfig, overrides: list[str], choices: dict[str, Any]
) -> tuple[DictConfig, Resume | None]:
    """The config that continues the run of the checkpoint `cfg` names (`cfg` when none): the
    run's own, with `overrides` (`choices`: their config-group options) on top; a
    CheckpointError names every key but FREE ones that they would change."""
    ckpt = checkpoint_to_resume(cfg)
    if ckpt is None:
        return cfg, None
    if not ckpt.is_file():
        read_checkpoint(ckpt)  # raises the message for a missing file or a folder
    run_dir = ckpt.absolute().parent.parent
    from_checkpoint = not (run_dir / "config.yaml").is_file()
    if from_checkpoint:
        # The sections the checkpoint stores; the length, schedule and seed come from the
        # command line.
        saved = OmegaConf.create(read_checkpoint(ckpt)["motion"]["config"])
    else:
        saved = OmegaConf.load(run_dir / "config.yaml")
    run_choices = None
    with contextlib.suppress(Exception):  # absent (a run started in-process): compare values
        hydra_yaml = OmegaConf.load(run_dir / ".hydra" / "hydra.yaml")
        run_choices = OmegaConf.to_container(hydra_yaml.hydra.runtime.choices)

    raw, saved_raw = OmegaConf.to_container(cfg), OmegaConf.to_container(saved)
    # Keys added to the project since the run: today's defaults.
    restored = OmegaConf.create({**raw, **saved_raw})
    for key in FROM_HERE:  # unresolved: they point at this run's folder, not yet created
        _put(restored, key, _raw(raw, key))
    _put(restored, "ckpt_path", str(ckpt))
    parsed = OverridesParser.create().parse_overrides(list(overrides))
    parents = run_dir.parents  # <log_dir>/<task>/runs/<name>/<time>, .../multiruns/<time>/<job>
    if len(parents) > 3 and parents[1].name in ("runs", "multiruns"):
        if not any(_under(o.key_or_group, ("paths",)) for o in parsed):
            # Beside the run, under the outputs folder it used, not under this machine's.
            _put(restored, "paths.log_dir", str(parents[3]))

    applied, conflicts = [], []
    for override in parsed:
        group, text = override.key_or_group, override.input_line
        if group in ("ckpt_path", "resume"):
            continue
        applied.append(text)
        key = group.replace("/", ".")
        if _under(key, FROM_HERE):
            continue
        if _free(key):
            _put(restored, key, _raw(raw, key))
            # A trainer=... option brings the Trainer, not its numerics: keep the run's.
            for kept in (k for k in COMPUTES if _under(k, (key,))):
                _put(restored, kept, _raw(saved_raw, kept))
        elif group in choices and run_choices is not None:  # compared by name
            if run_choices.get(group) != choices.get(group):
                conflicts.append(f"{text}: the run used {group}={run_choices.get(group)}")
        elif group in choices or not from_checkpoint or key.split(".")[0] in saved:
            # By value (else the command line's); a group option by the run's keys under it,
            # all of them for one that is no key (experiment=... can set any).
            option = group in choices and not isinstance(OmegaConf.select(cfg, key), DictConfig)
            now, then = _leaves(cfg, "" if option else key), _leaves(saved, "" if option else key)
            origin = f" (from {text})" if group in choices else ""
            conflicts += [
                f"{k}: checkpoint {then[k]}, command line {now.get(k, 'absent')}{origin}"
                for k in sorted(then)
                if now.get(k, "absent") != then[k]
            ]
    if conflicts:

        def word(key: str) -> str:  # "trainer.* except trainer.precision"
            node = key == "paths" or isinstance(OmegaConf.select(saved, key), DictConfig)
            kept = ", ".join(k for k in COMPUTES if _under(k, (key,)))
            return key + ".*" * node + f" except {kept}" * bool(kept)

        raise CheckpointError(
            f"cannot resume {ckpt} with settings other than its run's: {'; '.join(conflicts)}. "
            "A resumed run keeps its own settings; only these may differ: "
            f"{', '.join(map(word, (*FREE, 'paths')))}. Leave these overrides out, or start a "
            "new run."
        )
    OmegaConf.set_struct(restored, True)
    return restored, Resume(ckpt, run_dir, applied, from_checkpoint, run_choices)


# (config, Resume) prepared by the CLI's callback before the run folder existed, for this
# process's run: src.train finds its config prepared and does not restore and check it again.
_prepared: tuple[dict, Resume | None] | None = None


def prepare_training(
    cfg: DictConfig, overrides: list[str], choices: dict[str, Any]
) -> tuple[DictConfig, Resume | None]:
    """A training run's config, once per run: restore_run, check, build_parts: every refusal
    comes before the run folder and the data."""
    global _prepared
    if _prepared is not None and _prepared[0] == OmegaConf.to_container(cfg, resolve=False):
        return cfg, _prepared[1]
    restored, resume = restore_run(cfg, overrides, choices)
    check(restored, "train", resuming=resume is not None)
    build_parts(restored)
    _prepared = (OmegaConf.to_container(restored, resolve=False), resume)
    return restored, resume


def describe(resume: Resume, iteration: int) -> str:
    settings = (
        "the config sections stored in it"
        if resume.from_checkpoint
        else (resume.run_dir / "config.yaml")
    )
    return (
        f"resuming from {resume.checkpoint} at iteration {iteration} with the settings of "
        f"{settings}; command-line overrides on top: {', '.join(resume.applied) or 'none'}"
    )
