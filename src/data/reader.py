"""Read one exp-map motion text file into a float32 array.

Format (protocol §1.1, §1.5): one raw frame per line, ``n_columns`` comma-separated numbers, no
header (99 columns for H3.6M, 117 for CMU). The reference code parses line by line in Python;
here numpy's C parser does the work (about 10 s for all of H3.6M on one core), and only when it
fails or returns something wrong do we re-read the file line by line to report the first bad
line with its number.
"""

from __future__ import annotations

import math
import os
import re
import warnings
from pathlib import Path

import numpy as np

from src.data.errors import DataError, DataFormatError, DataNotFoundError

_F32_MAX = float(np.finfo(np.float32).max)
# Plain ASCII decimal notation, what numpy's parser takes: Python's float() alone would also
# accept "1_0" or non-ASCII digits, which only a damaged file contains.
_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?", re.ASCII)
_NON_FINITE = re.compile(r"[+-]?(nan|inf|infinity)", re.IGNORECASE)
_FIX = (
    "fix: replace the file with the copy from the original archive, "
    "or delete it and run with data.allow_partial=true"
)


def read_motion_file(path: str | os.PathLike, n_columns: int) -> np.ndarray:
    """Return the frames of ``path`` as a float32 array of shape (N, n_columns).

    Blank lines are skipped; LF, CRLF and a missing or extra trailing newline are accepted.
    Raises :class:`DataError` (naming the file, the line and the fix) for a missing or empty
    file, a line with the wrong number of fields, a non-numeric token or a NaN/inf value.
    """
    path = Path(path)
    if not path.is_file():
        raise DataNotFoundError(
            f"{path}: motion file not found (fix: check data.data_dir, or unpack the dataset "
            "archive again by deleting the unpacked folder)",
            missing=[str(path)],
        )
    if path.stat().st_size == 0:
        raise DataFormatError(f"{path}: file is empty ({_FIX})")

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "input contained no data" is reported below
            frames = np.loadtxt(path, delimiter=",", dtype=np.float32, ndmin=2, comments=None)
    except (ValueError, UnicodeDecodeError):
        frames = None
    except OSError as exc:  # e.g. no read permission: numpy would raise from deep inside
        raise DataError(
            f"{path}: cannot read the file ({exc.strerror or exc}) (fix: make it readable by "
            "this user)"
        ) from None
    if (
        frames is not None
        and frames.shape[0] > 0
        and frames.shape[1] == n_columns
        and np.isfinite(frames).all()
    ):
        return frames
    # Slow path: find and report the first bad line (or parse an odd but valid file,
    # e.g. one with a byte-order mark or whitespace-only lines).
    return _scan(path, n_columns)


def _scan(path: Path, n_columns: int) -> np.ndarray:
    rows: list[list[float]] = []
    with open(path, encoding="utf-8-sig", errors="replace") as fh:
        for lineno, line in enumerate(fh, start=1):
            text = line.strip()
            if not text:
                continue
            tokens = text.split(",")
            where = f"{path}:{lineno}"
            if len(tokens) != n_columns:
                hint = " (a trailing comma?)" if tokens[-1].strip() == "" else ""
                raise DataFormatError(
                    f"{where}: expected {n_columns} comma-separated numbers, found "
                    f"{len(tokens)}{hint} ({_FIX})"
                )
            row = []
            for col, token in enumerate(tokens):
                plain = token.strip()
                try:
                    if not (_NUMBER.fullmatch(plain) or _NON_FINITE.fullmatch(plain)):
                        raise ValueError(plain)
                    value = float(plain)
                except ValueError:
                    raise DataFormatError(
                        f"{where}: column {col + 1} holds {token.strip()[:40]!r}, which is not "
                        f"a number ({_FIX})"
                    ) from None
                # float32 overflow (|x| > 3.4e38) would turn into inf as well.
                if not math.isfinite(value) or abs(value) > _F32_MAX:
                    raise DataFormatError(
                        f"{where}: column {col + 1} holds {token.strip()!r}; NaN and infinite "
                        f"values are not valid motion data ({_FIX})"
                    )
                row.append(value)
            rows.append(row)
    if not rows:
        raise DataFormatError(f"{path}: file holds no data lines ({_FIX})")
    return np.asarray(rows, dtype=np.float32)


__all__ = ["read_motion_file", "DataError"]
