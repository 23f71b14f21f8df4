"""Errors of the data layer: each message names the file (and line) and the fix, so that a user
never has to read a numpy traceback to find out what is wrong with the data."""

from __future__ import annotations


class DataError(Exception):
    """A problem with the motion data or with how the data layer was configured; ``missing``
    lists the missing files (relative to data_dir) where that is the problem."""

    def __init__(self, message: str, missing: list[str] | None = None):
        super().__init__(message)
        self.missing = list(missing or [])
