"""Run folders, settled before anything is written, and the one way a refusal reaches the user.

Every run gets a new folder (src.data.files.claim_folder: runs started in the same second get
`<time>` and `<time>-1`). A folder named on the command line (`hydra.run.dir=...`) is used as
given, and refused when it already holds a run. `PrepareRun`, a Hydra callback, restores and
checks a training run's config before its folder exists, so a refused config creates none;
what is found later (a misspelt action) removes the folder made for it.
"""

from __future__ import annotations

import contextlib
import copy
import os
import re
import shutil
import sys
from pathlib import Path
from typing import NoReturn

from hydra.core.hydra_config import HydraConfig
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf, open_dict, read_write

from src.data.errors import DataError
from src.data.files import claim_folder
from src.lit.checkpoints import CheckpointError
from src.lit.config import ConfigError
from src.lit.factory import PROJECT_ROOT
from src.lit.predictor import NonFiniteLossError
from src.lit.resume import prepare_training

# The project's errors for a user's mistake (bad data, config, checkpoint, a diverged run): a
# refused run leaves nothing behind, and the command line prints them as one line.
USER_ERRORS = (DataError, ConfigError, CheckpointError, NonFiniteLossError)


def refuse(err: object) -> NoReturn:
    """What a user sees instead of a traceback: `error: <what is wrong and the fix>`, status 2."""
    print(f"error: {err}", file=sys.stderr)
    sys.exit(2)


def path_safe(text: str) -> str:
    """`text` with every character Hydra's override parser would stop at (or a shell would
    expand) replaced by `_`, so that a sweep job's folder works as printed in `ckpt_path=...`."""
    return re.sub(r"[^A-Za-z0-9_.+@-]", "_", str(text))


def training_run_name(ckpt_path: str | Path) -> str:
    """The name of the training run a checkpoint belongs to: `run_name` of the run's
    config.yaml (<run>/checkpoints/<file>.ckpt), else the run folder's name (its parent's when
    the folder is a timestamp)."""
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
    """The run_name of an evaluation or visualisation (conf/eval.yaml): the training run and
    checkpoint it evaluates, e.g. li2018_h36m_last; <model>_<data> for a baseline,
    predictions_<file stem>_<data> for a file of predictions."""
    if ckpt_path:
        return f"{training_run_name(ckpt_path)}_{Path(str(ckpt_path)).stem}"
    if predictions:
        return f"predictions_{Path(str(predictions)).stem}_{data or 'data'}"
    return f"{model or 'checkpoint'}_{data or 'data'}"


def register_resolvers() -> None:
    """The resolvers conf/ uses; registered when this module is imported (src.cli, compose)."""
    for name, resolver in (("project_root", lambda: str(PROJECT_ROOT)),
                           ("evaluated", evaluated_name), ("path_safe", path_safe)):  # fmt: skip
        if not OmegaConf.has_resolver(name):
            OmegaConf.register_new_resolver(name, resolver)


register_resolvers()


def holds_run(folder: Path) -> bool:
    return (folder / "config.yaml").exists() or any(folder.glob("checkpoints/*.ckpt"))


_claimed: dict = {}  # this process's folder: {"folder", "created", "before", "parents"}


def claim_run_folder(folder: str | os.PathLike, exact: bool = False) -> Path:
    """Create this run's folder and return it; no other process can get the same one.
    exact=True: the user named it; an existing folder is used only if it holds no run (Hydra's
    .hydra/, created here, is the claim)."""
    folder = Path(folder)
    parents = [p for p in folder.parents if not p.exists()]
    if not exact:
        folder = claim_folder(folder)
        _claimed.update(folder=folder, created=True, before=set(), parents=parents)
        return folder
    created = not folder.exists()
    folder.mkdir(parents=True, exist_ok=True)
    before = set(os.listdir(folder))
    try:
        (folder / ".hydra").mkdir()
    except FileExistsError:
        taken = True
    else:
        taken = holds_run(folder)
        if taken:
            (folder / ".hydra").rmdir()
    if taken:
        raise ConfigError(
            f"the run folder {folder} (hydra.run.dir) already holds a run; nothing was "
            "written to it. Name another folder, or leave hydra.run.dir out to get a new "
            "timestamped one."
        )
    _claimed.update(folder=folder, created=created, before=before, parents=parents)
    return folder


@contextlib.contextmanager
def nothing_left_if_refused(started: str | None = "config.yaml"):
    """Around an entry point's work: a user error raised inside removes what this process put
    into the run folder, unless the run had started (its file `started` exists; None: never),
    then goes on to the one-line message."""
    try:
        yield
    except USER_ERRORS:
        folder = Path(HydraConfig.get().runtime.output_dir)
        claimed = _claimed.get("folder")
        if claimed is None or claimed.resolve() != folder.resolve():
            raise
        if started is not None and (folder / started).exists():
            raise
        if _claimed["created"]:
            shutil.rmtree(folder, ignore_errors=True)
            for parent in _claimed["parents"]:
                with contextlib.suppress(OSError):  # only if empty: another run may use it
                    parent.rmdir()
        else:
            for name in set(os.listdir(folder)) - _claimed["before"]:
                path = folder / name
                shutil.rmtree(path) if path.is_dir() else path.unlink(missing_ok=True)
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
    """For a training run: restore the resumed run's settings and check them
    (src.lit.resume.prepare_training); then, for any entry point, claim a run folder no other
    process can get. In that order, so a refused config creates no folder, and Hydra writes
    only into the folder claimed here. (Hydra turns an exception raised in a callback into a
    warning: a refusal exits here.)"""

    def on_run_start(self, config: DictConfig, config_name: str | None = None, **kwargs) -> None:
        from lightning.pytorch.utilities import rank_zero_only

        if rank_zero_only.rank != 0:  # DDP's other ranks: Lightning passes rank 0's folder
            return
        try:
            if config_name == "train":
                self._prepare_training(config)
            folder = _claim(config, "hydra.run.dir")
        except USER_ERRORS as err:
            refuse(err)
        with read_write(config.hydra.run):
            config.hydra.run.dir = str(folder)

    @staticmethod
    def _prepare_training(config: DictConfig) -> None:
        task = copy.deepcopy(config)
        with read_write(task), open_dict(task):
            del task["hydra"]
        overrides = list(config.hydra.overrides.task)
        choices = OmegaConf.to_container(config.hydra.runtime.choices)
        restored, resume = prepare_training(task, overrides, choices)
        if resume is None:
            return
        # The run's settings become this job's, so Hydra's .hydra/ and the folder's name
        # (run_name, task_name) are the resumed run's.
        values = OmegaConf.to_container(restored, resolve=False)
        given = {o.split("=", 1)[0].lstrip("+~") for o in overrides}
        with read_write(config), open_dict(config):
            for key in [k for k in config if k != "hydra"]:
                del config[key]
            for key, value in values.items():
                config[key] = value
            for group, option in (resume.run_choices or {}).items():
                if group in config.hydra.runtime.choices and group not in given:
                    config.hydra.runtime.choices[group] = option

    def on_multirun_start(self, config: DictConfig, **kwargs) -> None:
        """A sweep's folder is claimed the same way; its jobs, numbered, cannot collide."""
        if _given(config, "hydra.sweep.dir"):
            return
        folder = _claim(config, "hydra.sweep.dir")
        with read_write(config.hydra):
            config.hydra.sweep.dir = str(folder)
            # Each job's config is composed again from these overrides (Hydra's
            # load_sweep_config): without this one it would name the unclaimed folder.
            config.hydra.overrides.hydra.append(f'hydra.sweep.dir="{folder}"')
