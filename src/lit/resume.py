"""Resumes: a resume continues a run, not a config.

`restore_run` rebuilds the configuration from the run's own `config.yaml` (saved resolved,
beside its `checkpoints/`), and the command line's overrides go on top. An override that would
change what the run computes is refused; the length (`iterations`), where files live, logging
and the Trainer's settings may change.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import DictConfig, ListConfig, OmegaConf

from src.lit.checkpoints import LAST, CheckpointError, read_checkpoint
from src.lit.config import ConfigError, check
from src.lit.factory import build_parts

# Where files live on this machine: always taken from this command, never from the resumed run.
FROM_HERE = (
    "hydra",  # in a config composed in-process (and so in the config.yaml of such a run)
    "paths",
    "ckpt_path",
    "resume",
    "trainer.default_root_dir",
    "data.data_dir",
    "data.archive_dir",
    "data.archive",
)
# Restored from the run, but the command line may change them: they do not change what the
# run computes (the Trainer's device settings are the user's to adapt to the machine). Not
# `compile`: compiled dropout draws other masks than eager, so the resume would not be exact.
FREE = (
    "iterations",
    "run_name",
    "task_name",
    "checkpoint_every",
    "media_every",
    "progress_every_s",
    "trainer",
    "data.num_workers",
)
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


def checkpoint_to_resume(cfg: DictConfig) -> Path | None:
    """The checkpoint named by `resume=<run folder>` (its checkpoints/last.ckpt) or
    `ckpt_path=`."""
    resume, ckpt = cfg.get("resume"), cfg.get("ckpt_path")
    if not resume:
        return Path(str(ckpt)) if ckpt else None
    path = Path(str(resume))
    target = path
    if path.is_dir():  # the run folder, or its checkpoints/ (named, too, by a user)
        target = path / LAST if (path / LAST).is_file() else path / "checkpoints" / LAST
    if ckpt and Path(str(ckpt)) != target:
        raise ConfigError(
            f"resume={resume} and ckpt_path={ckpt} name different checkpoints; give only one."
        )
    return target


def _plain(value: Any) -> Any:
    if isinstance(value, (DictConfig, ListConfig)):
        return OmegaConf.to_container(value, resolve=True)
    return value


def _leaves(root: DictConfig, path: str = "") -> dict[str, Any]:
    """Resolved leaves under `path` (dotted keys), leaving out FROM_HERE and FREE keys before
    resolving: those may point at this machine's Hydra state, which is not set up yet."""
    node = OmegaConf.select(root, path) if path else root
    out: dict[str, Any] = {}

    def walk(value: Any, key: str) -> None:
        if _under(key, FROM_HERE) or _free(key):
            return
        if isinstance(value, dict) and value:
            for k, v in value.items():
                walk(v, f"{key}.{k}" if key else str(k))
        else:
            out[key] = _plain(OmegaConf.select(root, key))

    walk(OmegaConf.to_container(node, resolve=False) if isinstance(node, DictConfig) else {}, path)
    return out


def _run_choices(run_dir: Path) -> dict[str, str] | None:
    try:
        hydra_cfg = OmegaConf.load(run_dir / ".hydra" / "hydra.yaml")
        return dict(OmegaConf.to_container(hydra_cfg.hydra.runtime.choices))
    except Exception:  # absent (a run started in-process) or unreadable: compare values
        return None


def _raw(container: dict, key: str) -> Any:
    """The unresolved value at a dotted key of a plain container, or _ABSENT."""
    value: Any = container
    for part in key.split("."):
        if not isinstance(value, dict) or part not in value:
            return _ABSENT
        value = value[part]
    return value


def _set(cfg: DictConfig, key: str, value: Any) -> None:
    OmegaConf.update(cfg, key, value, merge=False, force_add=True)


def _remove(cfg: DictConfig, key: str) -> None:
    parent, _, leaf = key.rpartition(".")
    node = OmegaConf.select(cfg, parent) if parent else cfg
    if isinstance(node, DictConfig) and leaf in node:
        del node[leaf]


def _shown(value: Any) -> Any:
    return "absent" if value is _ABSENT else value


def _group_conflicts(
    group: str,
    text: str,
    cfg: DictConfig,
    saved: DictConfig,
    choices: dict[str, Any],
    run_choices: dict[str, str] | None,
) -> list[str]:
    """A config-group option beside a resume must be the run's own: compared by name where
    the run recorded its options (.hydra/hydra.yaml), else by the values it gives."""
    node_key = group.replace("/", ".")
    if _under(node_key, FROM_HERE) or _free(node_key):
        return []
    if run_choices is not None:
        if run_choices.get(group) != choices.get(group):
            return [f"{text}: the run used {group}={run_choices.get(group)}"]
        return []
    # A group of the global package (experiment=...) can set any key: compare them all.
    node = node_key if isinstance(OmegaConf.select(cfg, node_key), DictConfig) else ""
    now, then = _leaves(cfg, node), _leaves(saved, node)
    return [
        f"{k}: checkpoint {then[k]}, command line {_shown(now.get(k, _ABSENT))} (from {text})"
        for k in sorted(then)
        if now.get(k, _ABSENT) != then[k]
    ]


def _may_change(saved: DictConfig) -> str:
    """FREE and COMPUTES in words ("trainer.* except trainer.precision"), so that the refusal
    says what the code allows."""
    words = []
    for key in (*FREE, "paths"):
        node = isinstance(OmegaConf.select(saved, key, default=None), DictConfig) or key == "paths"
        kept = [k for k in COMPUTES if _under(k, (key,))]
        words.append(f"{key}.*" if node else key)
        if kept:
            words[-1] += f" except {', '.join(kept)}"
    return ", ".join(words)


def outputs_folder_of(run_dir: Path) -> Path | None:
    """The paths.log_dir a run folder was made under, <log_dir>/<task>/runs/<name>/<time> or
    <log_dir>/<task>/multiruns/<time>/<job> (conf/hydra/default.yaml); None for another
    layout."""
    parents = run_dir.absolute().parents
    if len(parents) > 3 and parents[1].name in ("runs", "multiruns"):
        return parents[3]
    return None


def restore_run(
    cfg: DictConfig, overrides: list[str], choices: dict[str, Any]
) -> tuple[DictConfig, Resume | None]:
    """The configuration that continues the run of the checkpoint `cfg` names: the run's own,
    with `overrides` (the command line; `choices` its config-group options) on top.

    Raises CheckpointError naming every key the overrides would change, other than FREE ones.
    Without a checkpoint to resume, returns `cfg` unchanged.
    """
    ckpt = checkpoint_to_resume(cfg)
    if ckpt is None:
        return cfg, None
    if not ckpt.is_file():
        read_checkpoint(ckpt)  # raises the message for a missing file or a folder
    run_dir = ckpt.absolute().parent.parent
    if (run_dir / "config.yaml").is_file():
        saved = OmegaConf.load(run_dir / "config.yaml")
        from_checkpoint = False
    else:
        # The sections the checkpoint stores; the length, schedule and seed come from the
        # command line, and an epoch stays `val_every` iterations (set below, not compared).
        saved = OmegaConf.create(read_checkpoint(ckpt)["motion"]["config"])
        _remove(saved, "data.steps_per_epoch")
        from_checkpoint = True
    run_choices = _run_choices(run_dir)

    raw = OmegaConf.to_container(cfg, resolve=False)
    restored = OmegaConf.create(OmegaConf.to_container(saved, resolve=False))
    for key, value in raw.items():  # keys added to the project since the run: today's defaults
        if key not in restored:
            restored[key] = value
    for key in FROM_HERE:  # unresolved: they point at this run's folder, not yet created
        value = _raw(raw, key)
        if value is not _ABSENT:
            _set(restored, key, value)
        elif key == "hydra":
            _remove(restored, key)
    _set(restored, "ckpt_path", str(ckpt))
    if from_checkpoint:
        _set(restored, "data.steps_per_epoch", "${val_every}")
    parsed = OverridesParser.create().parse_overrides(list(overrides))
    log_dir = outputs_folder_of(run_dir)
    if log_dir is not None and not any(_under(o.key_or_group, ("paths",)) for o in parsed):
        # The new folder goes beside the run, under the outputs folder the run used
        # (its paths.log_dir), not under this machine's default.
        _set(restored, "paths.log_dir", str(log_dir))

    applied, conflicts = [], []
    for override in parsed:
        key = override.key_or_group
        if key in ("ckpt_path", "resume"):
            continue
        text = override.input_line
        applied.append(text)
        if key in choices:  # a config group: model=..., data=..., trainer=...
            conflicts += _group_conflicts(key, text, cfg, saved, choices, run_choices)
            node_key = key.replace("/", ".")
            if _free(node_key):
                _set(restored, node_key, _raw(raw, node_key))
                # A trainer=... option brings the Trainer, not its numerics: keep the run's.
                for key in (k for k in COMPUTES if _under(k, (node_key,))):
                    kept = OmegaConf.select(saved, key, default=_ABSENT)
                    if kept is _ABSENT:
                        _remove(restored, key)
                    else:
                        _set(restored, key, kept)
            continue
        if _under(key, FROM_HERE):
            continue
        if _free(key):
            if override.is_delete():
                _remove(restored, key)
            else:
                _set(restored, key, _raw(raw, key))
            continue
        if from_checkpoint and key.split(".")[0] not in saved:
            continue  # a section the checkpoint does not store: the command line's
        old = _plain(OmegaConf.select(saved, key, default=_ABSENT))
        new = _ABSENT if override.is_delete() else _plain(OmegaConf.select(cfg, key))
        if old != new:
            conflicts.append(f"{key}: checkpoint {_shown(old)}, command line {_shown(new)}")
    if conflicts:
        raise CheckpointError(
            f"cannot resume {ckpt} with settings other than its run's: "
            + "; ".join(conflicts)
            + f". A resumed run keeps its own settings; only these may differ: "
            f"{_may_change(saved)}. Leave these overrides out, or start a new run."
        )
    OmegaConf.set_struct(restored, True)
    return restored, Resume(ckpt, run_dir, applied, from_checkpoint, run_choices)


# (config, Resume) prepared by the CLI's callback before the run folder existed, for this
# process's run: src.train finds its config prepared and does not restore and check it again.
_prepared: tuple[dict, Resume | None] | None = None


def prepare_training(
    cfg: DictConfig, overrides: list[str], choices: dict[str, Any]
) -> tuple[DictConfig, Resume | None]:
    """The config a training run runs with, once per run: the resumed run's own settings with
    the command line's on top (restore_run), checked (src.lit.config.check), and the objects
    whose constructors check their own arguments built once (factory.build_parts), so that
    every refusal comes before the run folder and the data."""
    global _prepared
    plain = OmegaConf.to_container(cfg, resolve=False)
    if _prepared is not None and _prepared[0] == plain:
        return cfg, _prepared[1]
    restored, resume = restore_run(cfg, overrides, choices)
    check(restored, "train", resuming=resume is not None)
    build_parts(restored)
    _prepared = (OmegaConf.to_container(restored, resolve=False), resume)
    return restored, resume


def describe(resume: Resume, iteration: int) -> str:
    extra = ", ".join(resume.applied) if resume.applied else "none"
    if resume.from_checkpoint:  # no run folder around it: the folder above names no run
        start = (
            f"resuming from {resume.checkpoint} at iteration {iteration}, with the config "
            "sections stored in the checkpoint (no config.yaml beside it)"
        )
    else:
        start = (
            f"resuming the run {resume.run_dir} at iteration {iteration} from "
            f"{resume.checkpoint}, with its settings ({resume.run_dir / 'config.yaml'})"
        )
    return f"{start}; command-line overrides on top: {extra}"
