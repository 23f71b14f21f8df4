"""Read one exp-map motion text file (protocol §1.1, §1.5: one raw frame per line, 99 (H3.6M)
or 117 (CMU) comma-separated numbers, no header) into a float32 array. numpy's C parser does the
work (about 10 s for all of H3.6M on one core); only when it fails or returns something wrong
is the file read again line by line, to report the first bad line with its number."""

from __future__ import annotations

import os
import re
import warnings
from pathlib import Path

import numpy as np

from src.data.errors import DataError

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
    """The frames of ``path`` as float32 (N, n_columns). Blank lines, LF or CRLF and a missing
    or extra final newline are accepted; a missing or empty file, a line with the wrong number
    of fields, a non-numeric token or a NaN/inf value raise a DataError naming file and line."""
    path = Path(path)
    if not path.is_file():
        raise DataError(
            f"{path}: motion file not found (fix: check data.data_dir, or unpack the dataset "
            "archive again by deleting the unpacked folder)"
        )
    if path.stat().st_size == 0:
        raise DataError(f"{path}: file is empty ({_FIX})")
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
    if frames is not None and len(frames) and frames.shape[1] == n_columns:
        if np.isfinite(frames).all():
            return frames
    # Find and report the first bad line (or parse an odd but valid file, e.g. one with a
    # byte-order mark or whitespace-only lines).
    rows: list[list[float]] = []
    with open(path, encoding="utf-8-sig", errors="replace") as fh:
        for lineno, line in enumerate(fh, start=1):
            tokens = [t.strip() for t in line.strip().split(",")]
            if tokens == [""]:
                continue
            if len(tokens) != n_columns:
                hint = " (a trailing comma?)" if tokens[-1] == "" else ""
                raise DataError(
                    f"{path}:{lineno}: expected {n_columns} comma-separated numbers, found "
                    f"{len(tokens)}{hint} ({_FIX})"
                )
            for col, token in enumerate(tokens, start=1):
                if not (_NUMBER.fullmatch(token) or _NON_FINITE.fullmatch(token)):
                    raise DataError(
                        f"{path}:{lineno}: column {col} holds {token[:40]!r}, which is not a "
                        f"number ({_FIX})"
                    )
                if not abs(float(token)) <= _F32_MAX:  # NaN, inf, or inf once in float32
                    raise DataError(
                        f"{path}:{lineno}: column {col} holds {token!r}; NaN and infinite "
                        f"values are not valid motion data ({_FIX})"
                    )
            rows.append([float(t) for t in tokens])
    if not rows:
        raise DataError(f"{path}: file holds no data lines ({_FIX})")
    return np.asarray(rows, dtype=np.float32)
