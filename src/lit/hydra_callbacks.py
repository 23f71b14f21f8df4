"""Hydra callbacks: checks that must run before Hydra itself creates the run folder."""

from __future__ import annotations

import os
import sys
from pathlib import Path

from hydra.experimental.callback import Callback
from omegaconf import DictConfig


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
