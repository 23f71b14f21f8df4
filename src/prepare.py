"""What a command settles before its run folder is made (Hydra's `PrepareRun` callback): a
resumed run's config, its own with the command line on top (`restore_run`: where files live is
this command's, FROM_HERE; the length, logging and the Trainer's settings may change, FREE; an
override of anything else is refused naming each key with both values); every job of a training
sweep checked before the first starts (`check_sweep`); the run folder claimed, or a resumed
run's own folder continued. And `compose_config`: a config composed in-process as
`python -m src.<name>` would compose it (report, notebooks, tests)."""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, is_dataclass
from pathlib import Path
from typing import Any

import hydra
from hydra import compose, initialize_config_dir
from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.errors import HydraException
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, ListConfig, OmegaConf, open_dict, read_write

from src.build import build_parts
from src.cli import CONF_DIR, USER_ERRORS, claim_run_folder, refuse, register_resolvers
from src.config import ConfigError, check
from src.lit.checkpoints import LAST, CheckpointError, read_checkpoint


def compose_config(
    config_name: str,
    overrides: list[str],
    output_dir: str | Path,
    data_dir: str | Path | None = None,
) -> DictConfig:
    """The config of `conf/<config_name>.yaml` with `overrides`, run folder `output_dir`; sets
    Hydra's global state so that `${hydra:...}` interpolations resolve, as in a real run."""
    register_resolvers()
    GlobalHydra.instance().clear()
    extra = [] if data_dir is None else [f"paths.data_dir={data_dir}"]
    overrides = [f"paths.log_dir={output_dir}", *extra, *overrides]
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose(config_name, overrides=overrides, return_hydra_config=True)
    with open_dict(cfg):
        cfg.hydra.runtime.output_dir = str(output_dir)
        cfg.hydra.job.num = 0
    HydraConfig().set_config(cfg)
    return cfg


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
    return f"{start}; command-line overrides on top: {', '.join(resume.applied) or 'none'}"


def _given(config: DictConfig, key: str) -> bool:
    return any(o.split("=", 1)[0].lstrip("+~") == key for o in config.hydra.overrides.hydra)


def _claim(config: DictConfig, key: str) -> Path:
    try:
        return claim_run_folder(str(OmegaConf.select(config, key)), exact=_given(config, key))
    except OSError as err:
        refuse(
            f"cannot write the run folder {OmegaConf.select(config, key)}: {err.strerror} "
            f"({err.filename}). Point paths.log_dir (or {key}) at a writable folder."
        )


class PrepareRun(Callback):
    """Restore and check a training run's config (prepare_training), then claim the run folder
    Hydra writes into. A refusal exits here: Hydra turns a callback's exception into a warning."""

    def on_run_start(self, config: DictConfig, config_name: str | None = None, **kwargs) -> None:
        from lightning.pytorch.utilities import rank_zero_only

        if rank_zero_only.rank != 0:  # DDP's other ranks: Lightning passes rank 0's folder
            return
        try:
            resume = self._prepare_training(config) if config_name == "train" else None
            if resume is not None and resume.in_place and not _given(config, "hydra.run.dir"):
                folder = resume.run_dir  # continued where it is: its checkpoints, log, curves
                stamp = time.strftime("%Y-%m-%d_%H-%M-%S")
                with read_write(config.hydra):  # the run's own .hydra/ files stay as they are
                    config.hydra.output_subdir = f"{config.hydra.output_subdir}/resumed-{stamp}"
            else:
                folder = _claim(config, "hydra.run.dir")
        except USER_ERRORS as err:
            refuse(err)
        with read_write(config.hydra.run):
            config.hydra.run.dir = str(folder)

    @staticmethod
    def _prepare_training(config: DictConfig) -> Resume | None:
        task = OmegaConf.masked_copy(config, [k for k in config if k != "hydra"])
        overrides = list(config.hydra.overrides.task)
        choices = OmegaConf.to_container(config.hydra.runtime.choices)
        restored, resume = prepare_training(task, overrides, choices)
        if resume is None:
            return None
        # The run's settings become this job's, before its folder is named from them
        # (run_name, task_name, paths.log_dir); .hydra/ records the run's options.
        given = {o.split("=", 1)[0].lstrip("+~") for o in overrides}
        with read_write(config), open_dict(config):
            for key, value in OmegaConf.to_container(restored, resolve=False).items():
                node = config._get_node(key)  # every key of `config` but hydra
                if isinstance(node, DictConfig) and is_dataclass(OmegaConf.get_type(node)):
                    node.merge_with(value)  # typed by src/config.py: its keys are fixed
                else:
                    config[key] = value
            for group, option in (resume.run_choices or {}).items():
                if group in config.hydra.runtime.choices and group not in given:
                    config.hydra.runtime.choices[group] = option
        return resume

    def on_multirun_start(
        self, config: DictConfig, config_name: str | None = None, **kwargs
    ) -> None:
        """Every job's config is checked before the first starts; the sweep's folder is claimed
        the same way as a run's; its jobs, numbered, cannot collide."""
        if config_name == "train":
            check_sweep(config)
        if _given(config, "hydra.sweep.dir"):
            return
        folder = _claim(config, "hydra.sweep.dir")
        with read_write(config.hydra):
            config.hydra.sweep.dir = str(folder)
            # Each job's config is composed again from these (Hydra's load_sweep_config).
            config.hydra.overrides.hydra.append(f'hydra.sweep.dir="{folder}"')


BASIC_SWEEPER = "hydra._internal.core_plugins.basic_sweeper.BasicSweeper"


def sweep_jobs(config: DictConfig) -> tuple[list[list[str]], bool]:
    """The override lists of the jobs the sweep `config` will launch, and whether they are all
    of them: the basic sweeper's, expanded as it expands them; another sweeper (Optuna) draws
    its values as the study goes, so one list: the command line's fixed values, every trial's."""
    arguments = list(config.hydra.overrides.task)
    parser = OverridesParser.create(config_loader=GlobalHydra.instance().config_loader())
    sweeper = hydra.utils.get_class(config.hydra.sweeper._target_)
    # By name: Hydra's plugin discovery imports its sweepers' modules again (other classes).
    if BASIC_SWEEPER in {f"{c.__module__}.{c.__qualname__}" for c in sweeper.__mro__}:
        params = config.hydra.sweeper.get("params") or {}
        parsed = parser.parse_overrides([f"{k}={v}" for k, v in params.items()] + arguments)
        (jobs,) = BasicSweeper.split_arguments(parsed, max_batch_size=None)
        return jobs, True
    parsed = parser.parse_overrides(arguments)
    fixed = [f"{o.get_key_element()}={o.get_value_element_as_str()}" for o in parsed
             if not o.is_sweep_override()]  # fmt: skip
    return [fixed], False


def check_sweep(config: DictConfig) -> None:
    """Refuse a training sweep, before its first job, if any job's config would be refused:
    each is composed as its launcher will compose it and checked as a single run is
    (prepare_training). Otherwise job 5's bad value stops the sweep hours in, after jobs 0-4."""
    jobs, expanded = sweep_jobs(config)
    loader = GlobalHydra.instance().config_loader()
    for num, overrides in enumerate(jobs):
        try:
            job = loader.load_sweep_config(config, list(overrides))
        except HydraException as err:  # Hydra's refusal of a value (its type: src/config.py)
            if not expanded:  # Optuna's fixed values composed already (the sweep's config)
                return
            text = f"{err} {err.__cause__ or ''}".split("Config search path:")[0].split()
            words = " ".join(x for x in text if not x.startswith("object_type"))
            refuse(f"job {num} of the sweep ({' '.join(overrides)}) cannot be composed, so no "
                   f"job of the sweep was started: {words}")  # fmt: skip
        task = OmegaConf.masked_copy(job, [k for k in job if k != "hydra"])
        choices = OmegaConf.to_container(job.hydra.runtime.choices)
        try:
            prepare_training(task, list(overrides), choices)
        except USER_ERRORS as err:
            which = f"job {num} of the sweep's {len(jobs)}" if expanded else "every trial"
            refuse(
                f"{which} ({' '.join(overrides) or 'no overrides'}) would be refused, so no "
                f"job of the sweep was started: {err}"
            )
