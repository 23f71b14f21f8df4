"""Hydra callbacks: what must happen before Hydra itself creates the run folder."""

from __future__ import annotations

import copy
import os
import re
import sys
from pathlib import Path

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf, open_dict, read_write


def path_safe(text: str) -> str:
    """`text` with every character Hydra's override parser would stop at (or a shell would
    expand) replaced by `_`, so that a sweep job's folder works as printed in `ckpt_path=...`."""
    return re.sub(r"[^A-Za-z0-9_.+@-]", "_", str(text))


if not OmegaConf.has_resolver("path_safe"):
    OmegaConf.register_new_resolver("path_safe", path_safe)


def unwritable_reason(folder: str | os.PathLike) -> str | None:
    """Why `folder` cannot be created and written, or None if it can."""
    path = Path(folder).absolute()
    probe = path
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    if not probe.is_dir():
        return f"{probe} is a file, not a folder"
    if not os.access(probe, os.W_OK | os.X_OK):
        return f"{probe} is not writable by this user"
    return None


class CheckOutputWritable(Callback):
    """Fail with one clear line, before any work, when the run folder cannot be written."""

    def _check(self, folder: str) -> None:
        reason = unwritable_reason(folder)
        if reason:
            print(
                f"error: cannot write the run folder {folder}: {reason}. Point paths.log_dir "
                "(or hydra.run.dir / hydra.sweep.dir) at a writable folder.",
                file=sys.stderr,
            )
            sys.exit(2)

    def on_run_start(self, config: DictConfig, **kwargs) -> None:
        self._check(config.hydra.run.dir)

    def on_multirun_start(self, config: DictConfig, **kwargs) -> None:
        self._check(config.hydra.sweep.dir)


def _fail(message: str) -> None:
    print(f"error: {message}", file=sys.stderr)
    sys.exit(2)


def _given(config: DictConfig, key: str) -> bool:
    return any(o.split("=", 1)[0].lstrip("+~") == key for o in config.hydra.overrides.hydra)


class PrepareRun(Callback):
    """For a training run: restore the resumed run's settings and validate them; then, for any
    entry point, claim a run folder no other process can get. In that order, so a refused
    config creates no folder, and Hydra writes only into the folder claimed here."""

    def on_run_start(self, config: DictConfig, config_name: str | None = None, **kwargs) -> None:
        from lightning.pytorch.utilities import rank_zero_only

        from src.lit.run_folders import USER_ERRORS, claim_run_folder

        if rank_zero_only.rank != 0:  # DDP's other ranks: Lightning passes rank 0's folder
            return
        try:
            if config_name == "train":
                self._prepare_training(config)
            folder = claim_run_folder(
                str(config.hydra.run.dir), exact=_given(config, "hydra.run.dir")
            )
        except USER_ERRORS as err:
            _fail(str(err))
        except OSError as err:
            _fail(
                f"cannot create the run folder {config.hydra.run.dir}: {err}. Point "
                "paths.log_dir (or hydra.run.dir) at a writable folder."
            )
        with read_write(config.hydra.run):
            config.hydra.run.dir = str(folder)

    @staticmethod
    def _prepare_training(config: DictConfig) -> None:
        from src.lit.resume import restore_run
        from src.lit.validation import check_schedule, validate_train_config

        task = copy.deepcopy(config)
        with read_write(task), open_dict(task):
            del task["hydra"]
        choices = OmegaConf.to_container(config.hydra.runtime.choices)
        restored, resume = restore_run(task, list(config.hydra.overrides.task), choices)
        validate_train_config(restored)
        check_schedule(restored)
        if resume is None:
            return
        # The run's settings become this job's, so Hydra's .hydra/ and the folder's name
        # (run_name, task_name) are the resumed run's.
        values = OmegaConf.to_container(restored, resolve=False)
        given = {o.split("=", 1)[0].lstrip("+~") for o in config.hydra.overrides.task}
        with read_write(config), open_dict(config):
            for key in [k for k in config if k != "hydra" and k not in values]:
                del config[key]
            for key, value in values.items():
                if key != "hydra":
                    config[key] = value
            for group, option in (resume.run_choices or {}).items():
                if group in config.hydra.runtime.choices and group not in given:
                    config.hydra.runtime.choices[group] = option

    def on_multirun_start(self, config: DictConfig, **kwargs) -> None:
        """A sweep's folder is claimed the same way; its jobs, numbered, cannot collide."""
        from src.lit.run_folders import claim_run_folder

        if _given(config, "hydra.sweep.dir"):
            return
        try:
            folder = claim_run_folder(str(config.hydra.sweep.dir))
        except OSError as err:
            _fail(
                f"cannot create the sweep folder {config.hydra.sweep.dir}: {err}. Point "
                "paths.log_dir (or hydra.sweep.dir) at a writable folder."
            )
        with read_write(config.hydra):
            config.hydra.sweep.dir = str(folder)
            # Each job's config is composed again from these overrides (Hydra's
            # load_sweep_config): without this one it would name the unclaimed folder.
            config.hydra.overrides.hydra.append(f'hydra.sweep.dir="{folder}"')
