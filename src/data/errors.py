"""Exceptions of the data layer.

Every problem with the user's data (missing archive, missing files, malformed text, bad
arguments) raises a :class:`DataError` whose message names the file (and line) and the fix,
so that a user never has to read a numpy traceback to find out what is wrong.
"""

from __future__ import annotations


class DataError(Exception):
    """A problem with the motion data or with how the data layer was configured."""


class DataFormatError(DataError):
    """A motion text file is malformed (wrong column count, non-numeric or non-finite value)."""


class DataNotFoundError(DataError):
    """The dataset, its archive or some of its files cannot be found.

    ``missing`` lists the missing files relative to the data directory (empty when the whole
    dataset is absent).
    """

    def __init__(self, message: str, missing: list[str] | None = None):
        super().__init__(message)
        self.missing = list(missing or [])
