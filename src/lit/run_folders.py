"""Run folders, settled before anything is written, and the one way a refusal reaches the user.
Every run gets a new folder (`<time>`, `<time>-1`, ...); one named with `hydra.run.dir=...` is
refused when it holds a run. A resume continues in its run's own folder, Hydra's record of the
resume beside the run's (`.hydra/resumed-<time>/`). A refused config creates no folder
(`PrepareRun`); what is found later (a misspelt action) removes the folder made for it."""

from __future__ import annotations

import contextlib
import logging
import os
import re
import shutil
import sys
import time
from dataclasses import is_dataclass
from pathlib import Path
from typing import NoReturn

import hydra
from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.errors import HydraException
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf, open_dict, read_write

from src.config import ConfigError
from src.data.errors import DataError
from src.data.files import claim_folder
from src.lit.checkpoints import CheckpointError
from src.lit.factory import PROJECT_ROOT
from src.lit.predictor import NonFiniteLossError
from src.lit.resume import Resume, prepare_training

# A user's mistake (bad data, config, checkpoint, a diverged run): printed as one line.
USER_ERRORS = (DataError, ConfigError, CheckpointError, NonFiniteLossError)


def refuse(err: object) -> NoReturn:
    """What a user sees instead of a traceback: `error: <what is wrong and the fix>`, status 2."""
    print(f"error: {err}", file=sys.stderr)
    sys.exit(2)


def stop_interrupted() -> NoReturn:
    """What Ctrl-C ends a command with instead of a traceback: one line saying what became of
    its run folder (nothing_left_if_refused tidied it unless the run had started), status 130
    (128 + SIGINT, as a shell reports a Ctrl-C)."""
    where = ""
    if HydraConfig.initialized():
        folder = Path(HydraConfig.get().runtime.output_dir)
        if not folder.exists():
            where = f"; its unfinished run folder {folder} was removed"
        elif _claimed.get("tidied"):  # a folder named with hydra.run.dir, holding files before
            where = f"; what it had written into {folder} was removed, the rest left as it was"
        else:
            where = f"; the run folder {folder} is kept"
    print(f"interrupted (Ctrl-C){where}", file=sys.stderr)
    sys.exit(130)


class PrintedByRefuse(logging.Filter):
    """For the console handler (conf/hydra/default.yaml): a refusal logged for the run's
    train.log (`extra={"refusal": True}`) is on the console already, printed by `refuse`."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not getattr(record, "refusal", False)


def path_safe(text: str) -> str:
    """`text` with `_` for what stops Hydra's parser or a shell: a folder works in `ckpt_path=`."""
    return re.sub(r"[^A-Za-z0-9_.+@-]", "_", str(text))


def training_run_name(ckpt_path: str | Path) -> str:
    """`run_name` of the config.yaml of a checkpoint's run (<run>/checkpoints/<file>.ckpt),
    else the run folder's name (its parent's when the folder is a timestamp)."""
    path = Path(ckpt_path)
    run = path.parent.parent if path.parent.name == "checkpoints" else path.parent
    with contextlib.suppress(Exception):  # an unreadable config only loses the name
        name = OmegaConf.load(run / "config.yaml").get("run_name")
        if isinstance(name, str) and name:
            return name
    stamp = run.name.replace("-", "").replace("_", "")
    return run.parent.name if stamp.isdigit() else run.name


def evaluated_name(
    ckpt_path: str | None, model: str | None, data: str | None, predictions: str | None = None
) -> str:
    """The run_name of an evaluation (conf/eval.yaml): <training run>_<checkpoint file>,
    <model>_<data> for a baseline, predictions_<file stem>_<data> for a file of predictions."""
    if ckpt_path:
        return f"{training_run_name(ckpt_path)}_{Path(str(ckpt_path)).stem}"
    if predictions:
        return f"predictions_{Path(str(predictions)).stem}_{data or 'data'}"
    return f"{model or 'checkpoint'}_{data or 'data'}"


def register_resolvers() -> None:
    """The resolvers conf/ uses (registered on import, too)."""
    for name, resolver in (("project_root", lambda: str(PROJECT_ROOT)),
                           ("evaluated", evaluated_name), ("path_safe", path_safe)):  # fmt: skip
        OmegaConf.register_new_resolver(name, resolver, replace=True)


register_resolvers()


def holds_run(folder: Path) -> bool:
    return (folder / "config.yaml").exists() or any(folder.glob("checkpoints/*.ckpt"))


_claimed: dict = {}  # this process's folder, what it held before, the folders made for it


def claim_run_folder(folder: str | os.PathLike, exact: bool = False) -> Path:
    """Create this run's folder, which no other process can get. exact=True: the user named
    it; an existing one is used only if it holds no run (the .hydra/ made here is the claim)."""
    folder = Path(folder)
    made = [p for p in folder.parents if not p.exists()]
    if not exact:
        folder = claim_folder(folder)
        _claimed.update(folder=folder, before=set(), made=[folder, *made])
        return folder
    made = made if folder.exists() else [folder, *made]
    folder.mkdir(parents=True, exist_ok=True)
    before = set(os.listdir(folder))
    try:
        (folder / ".hydra").mkdir()  # one process alone can create it
        if holds_run(folder):
            (folder / ".hydra").rmdir()
            raise FileExistsError
    except FileExistsError:
        raise ConfigError(
            f"the run folder {folder} (hydra.run.dir) already holds a run; nothing was "
            "written to it. Name another folder, or leave hydra.run.dir out to get a new "
            "timestamped one."
        ) from None
    _claimed.update(folder=folder, before=before, made=made)
    return folder


@contextlib.contextmanager
def nothing_left_if_refused(started: str | None = "config.yaml"):
    """A user error or a Ctrl-C raised inside removes what this process put into the run
    folder, unless the run had started (its file `started` exists; None: never), and goes on:
    a folder is complete or gone, never half-written."""
    try:
        yield
    except (*USER_ERRORS, KeyboardInterrupt):
        folder = Path(HydraConfig.get().runtime.output_dir)
        claimed = _claimed.get("folder")
        mine = claimed is not None and claimed.resolve() == folder.resolve()
        if not mine or (started and (folder / started).exists()):
            raise
        _claimed["tidied"] = True
        for name in set(os.listdir(folder)) - _claimed["before"]:
            path = folder / name
            shutil.rmtree(path) if path.is_dir() else path.unlink(missing_ok=True)
        for made in _claimed["made"]:
            with contextlib.suppress(OSError):  # only if empty: another run may use a parent
                made.rmdir()
        raise


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
