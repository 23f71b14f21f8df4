"""Run folders, settled before anything is written.

Run folders are created with `os.mkdir`, which exactly one process can win: two runs started
in the same second (the resolution of the folder's timestamp) get `<time>` and `<time>-1`.
A folder named on the command line (`hydra.run.dir=...`) is used as given, and refused when it
already holds a run. A run refused for a user's mistake leaves nothing behind.
"""

from __future__ import annotations

import contextlib
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from omegaconf import OmegaConf

from src.data.errors import DataError
from src.lit.checkpoints import CheckpointError
from src.lit.factory import ConfigError
from src.lit.predictor import NonFiniteLossError

# The project's errors for a user's mistake (bad data, config, checkpoint, a diverged run): a
# refused run leaves nothing behind, and the command line prints them as one line (src/cli.py).
USER_ERRORS = (DataError, ConfigError, CheckpointError, NonFiniteLossError)


@dataclass
class _Claim:
    folder: Path
    created: bool  # False: a folder named by hand that existed (empty of runs) before
    before: set[str] = field(default_factory=set)
    parents: list[Path] = field(default_factory=list)  # created for it, deepest first


_claimed: _Claim | None = None


def claim_run_folder(folder: str | os.PathLike, exact: bool = False) -> Path:
    """Create this run's folder and return it; no other process can get the same one.

    exact=False: `folder` is a generated name; when taken, `-1`, `-2`, ... are tried.
    exact=True: the user named it; an existing folder is used only if it holds no run.
    """
    global _claimed
    folder = Path(folder)
    if exact:
        created = not folder.exists()
        folder.mkdir(parents=True, exist_ok=True)
        before = set(os.listdir(folder))
        holds_run = (folder / "config.yaml").exists() or any(folder.glob("checkpoints/*.ckpt"))
        try:
            # Hydra's .hydra/ is in every folder a CLI run used: creating it is the claim.
            (folder / ".hydra").mkdir()
        except FileExistsError:
            holds_run = True
        else:
            if holds_run:
                (folder / ".hydra").rmdir()
        if holds_run:
            raise ConfigError(
                f"the run folder {folder} (hydra.run.dir) already holds a run; nothing was "
                "written to it. Name another folder, or leave hydra.run.dir out to get a new "
                "timestamped one."
            )
        _claimed = _Claim(folder, created, before)
        return folder
    parents = [p for p in folder.parents if not p.exists()]
    candidate, n = folder, 0
    while True:
        try:
            candidate.mkdir()
        except FileExistsError:
            n += 1
            candidate = folder.with_name(f"{folder.name}-{n}")
        except FileNotFoundError:
            candidate.parent.mkdir(parents=True, exist_ok=True)
        else:
            _claimed = _Claim(candidate, created=True, parents=parents)
            return candidate


def discard_unstarted_run(folder: str | os.PathLike, started: str | None = "config.yaml") -> None:
    """Remove what this process put into `folder` when the run was refused before it started
    (no file `started` in it yet; None: any refusal): a refused run leaves nothing behind."""
    claim = _claimed
    folder = Path(folder)
    if claim is None or claim.folder.resolve() != folder.resolve():
        return
    if started is not None and (folder / started).exists():
        return
    if claim.created:
        shutil.rmtree(folder, ignore_errors=True)
        for parent in claim.parents:
            try:
                parent.rmdir()  # only if empty: another run may have started in it since
            except OSError:
                break
        return
    for name in set(os.listdir(folder)) - claim.before:
        path = folder / name
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)


@contextlib.contextmanager
def nothing_left_if_refused(started: str | None = "config.yaml"):
    """Around an entry point's work: a user error raised inside removes the run folder Hydra
    runs in (discard_unstarted_run, with `started`), then goes on to the one-line message."""
    try:
        yield
    except USER_ERRORS:
        discard_unstarted_run(HydraConfig.get().runtime.output_dir, started)
        raise


def training_run_name(ckpt_path: str | Path) -> str:
    """The name of the training run a checkpoint belongs to: `run_name` of the run's
    config.yaml (<run>/checkpoints/<file>.ckpt), else the run folder's name (its parent's when
    the folder is a timestamp)."""
    path = Path(ckpt_path)
    run = path.parent.parent if path.parent.name == "checkpoints" else path.parent
    config = run / "config.yaml"
    if config.is_file():
        try:
            name = OmegaConf.load(config).get("run_name")
        except Exception:  # noqa: BLE001 (an unreadable config only loses the name)
            name = None
        if isinstance(name, str) and name:
            return name
    stamp = run.name.replace("-", "").replace("_", "")
    return run.parent.name if stamp.isdigit() else run.name


def evaluated_name(
    ckpt_path: str | None, model: str | None, data: str | None, predictions: str | None = None
) -> str:
    """The run_name of an evaluation or visualisation (the `evaluated` resolver of
    conf/eval.yaml): the training run and checkpoint it evaluates, e.g. li2018_h36m_last, so
    that the folders of different models tell apart; <model>_<data> for a baseline,
    predictions_<file stem>_<data> for a file of predictions."""
    if ckpt_path:
        return f"{training_run_name(ckpt_path)}_{Path(str(ckpt_path)).stem}"
    if predictions:
        return f"predictions_{Path(str(predictions)).stem}_{data or 'data'}"
    return f"{model or 'checkpoint'}_{data or 'data'}"
