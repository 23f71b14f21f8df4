"""Read the exp-map motion text files (protocol §1.1, §1.5: one raw frame per line, 99 (H3.6M)
or 117 (CMU) comma-separated numbers, no header) into float32 arrays with numpy's C parser (about
10 s for all of H3.6M on one core); a file it fails on is read again line by line, to report the
first bad line. Each file is parsed once: ``<data_dir>/cache/<dataset>/`` holds one ``.npy`` per
file, named by the source's path, size and ``mtime_ns``, so a changed, new or vanished source
updates its own file only. Writes are atomic; a cache file that does not read back is parsed
again."""

from __future__ import annotations

import logging
import os
import re
import warnings
from collections.abc import Sequence
from contextlib import suppress
from pathlib import Path

import numpy as np

from src.data.errors import DataError
from src.data.files import atomic_write
from src.data.layout import DatasetSpec

log = logging.getLogger(__name__)

_F32_MAX = float(np.finfo(np.float32).max)
# Plain ASCII decimal notation, what numpy's parser takes (nan and inf are refused later, by
# name): Python's float() alone would also accept "1_0" or non-ASCII digits.
_NUMBER = re.compile(r"[+-]?((\d+\.?\d*|\.\d+)(e[+-]?\d+)?|nan|inf(inity)?)", re.ASCII | re.I)
# A cache file: the source's path with "/" as "__", its size and mtime_ns (load_sequences).
_CACHED = re.compile(r"(.+)\.\d+-\d+\.npy")
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
                if not _NUMBER.fullmatch(token):
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
        raise DataError(f"{path}: file holds no data lines: it is empty or blank ({_FIX})")
    return np.asarray(rows, dtype=np.float32)


def load_sequences(
    data_dir: str | os.PathLike, spec: DatasetSpec, relpaths: Sequence[str]
) -> dict[str, np.ndarray]:
    """Raw (50 Hz, all columns) float32 arrays of ``relpaths`` (relative to ``data_dir``), from
    the cache where valid, else parsed and cached (if the cache is not writable: not cached)."""
    data_dir = Path(data_dir)
    folder = data_dir / "cache" / spec.name
    out: dict[str, np.ndarray] = {}
    writable, parsing = True, False
    for rel in relpaths:
        source = data_dir / rel
        if not source.is_file():
            read_motion_file(source, spec.n_columns)  # raises, naming the file
        # stat taken before reading: if the file changes while we read it, the name is stale
        # and the next run parses it again.
        st = source.stat()
        stem = rel.removesuffix(".txt").replace("/", "__")
        npy = folder / f"{stem}.{st.st_size}-{st.st_mtime_ns}.npy"
        with suppress(OSError, ValueError, EOFError):
            arr = np.load(npy, allow_pickle=False)
            if arr.dtype == np.float32 and arr.ndim == 2 and arr.shape[1] == spec.n_columns:
                out[rel] = arr
                continue
        if not parsing:
            log.info("parsing %s text files into the cache %s", spec.name, folder)
        parsing = True
        arr = out[rel] = read_motion_file(source, spec.n_columns)
        if writable:
            try:
                for old in folder.glob(f"{stem}.*-*.npy"):  # the source's earlier versions
                    old.unlink()
                atomic_write(npy, lambda tmp, a=arr: np.save(tmp, a, allow_pickle=False))
            except OSError as exc:
                writable = False
                log.warning("cannot write the cache in %s (%s); parsing every time", folder, exc)

    # Forget the files of sources that are gone, and the earlier layout's (a manifest.json
    # beside <path>.npy files): they would never be read again.
    with suppress(OSError):  # a read-only cache stays as it is
        (folder / "manifest.json").unlink(missing_ok=True)
        for npy in folder.glob("[!.]*.npy"):  # not the temporary files of atomic_write
            cached = _CACHED.fullmatch(npy.name)
            if not cached or not (data_dir / f"{cached[1].replace('__', '/')}.txt").is_file():
                npy.unlink(missing_ok=True)
    return out
