"""Run folders and the one way a refusal reaches the user. Every run gets a new folder
(`<time>`, `<time>-1`, ...); one named with `hydra.run.dir=...` is refused when it holds a run.
A refused config creates no folder (src.prepare.PrepareRun checks it first); what is found later
(a misspelt action) removes the folder made for it (`nothing_left_if_refused`)."""

from __future__ import annotations

import contextlib
import logging
import os
import re
import shutil
import sys
from pathlib import Path
from typing import NoReturn

from hydra.core.hydra_config import HydraConfig
from omegaconf import OmegaConf

from src.config import ConfigError
from src.data.errors import DataError
from src.data.files import claim_folder
from src.lit.checkpoints import CheckpointError
from src.lit.factory import PROJECT_ROOT
from src.lit.predictor import NonFiniteLossError

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
