"""Read the exp-map motion text files (protocol §1.1, §1.5: one raw frame per line, 99 (H3.6M)
or 117 (CMU) comma-separated numbers, no header) into float32 arrays with numpy's C parser (about
10 s for all of H3.6M on one core); a file it fails on is read again line by line, to report the
first bad line. Each file is parsed once: ``<data_dir>/cache/<dataset>/`` holds one ``.npy`` per
file and ``manifest.json`` with each source's size and ``mtime_ns``, so a changed, new or vanished
source updates its own entry only. Writes are atomic; a cache file that does not read back right
is parsed again."""

from __future__ import annotations

import json
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


CACHE_VERSION = 1
MANIFEST = "manifest.json"


def load_sequences(
    data_dir: str | os.PathLike, spec: DatasetSpec, relpaths: Sequence[str]
) -> dict[str, np.ndarray]:
    """Raw (50 Hz, all columns) float32 arrays of ``relpaths`` (relative to ``data_dir``), from
    the cache where valid, else parsed and cached (if the cache is not writable: not cached)."""
    data_dir = Path(data_dir)
    folder = data_dir / "cache" / spec.name
    manifest = dict(version=CACHE_VERSION, dataset=spec.name, n_columns=spec.n_columns, files={})
    with suppress(OSError, ValueError, LookupError, TypeError, AttributeError):
        old = json.loads((folder / MANIFEST).read_text())
        same = (old["version"], old["n_columns"]) == (CACHE_VERSION, spec.n_columns)
        files = old["files"].values()
        if same and all({"size", "mtime_ns", "frames", "npy"} <= e.keys() for e in files):
            manifest = old
    entries: dict[str, dict] = manifest["files"]
    out: dict[str, np.ndarray] = {}
    writable, changed = True, False
    for rel in relpaths:
        st = (data_dir / rel).stat() if (data_dir / rel).is_file() else None  # None: reader says
        entry = entries.get(rel)
        if st and entry and (entry["size"], entry["mtime_ns"]) == (st.st_size, st.st_mtime_ns):
            with suppress(OSError, ValueError, EOFError):
                arr = np.load(folder / entry["npy"], allow_pickle=False)
                if arr.dtype == np.float32 and arr.shape == (entry["frames"], spec.n_columns):
                    out[rel] = arr
                    continue
        # stat taken before reading: if the file changes while we read it, the entry is stale
        # and the next run parses it again.
        if not changed:
            log.info("parsing %s text files into the cache %s", spec.name, folder)
        changed = True
        arr = out[rel] = read_motion_file(data_dir / rel, spec.n_columns)
        if writable:
            npy = rel.replace("/", "__").removesuffix(".txt") + ".npy"
            try:
                atomic_write(folder / npy, lambda tmp, a=arr: np.save(tmp, a, allow_pickle=False))
            except OSError as exc:
                writable = False
                log.warning("cannot write the cache in %s (%s); parsing every time", folder, exc)
                continue
            entries[rel] = dict(size=st.st_size, mtime_ns=st.st_mtime_ns, frames=len(arr), npy=npy)

    # Forget entries whose source file is gone (they would never be valid again).
    gone = [rel for rel in entries if not (data_dir / rel).is_file()]
    for rel in gone:
        (folder / entries.pop(rel)["npy"]).unlink(missing_ok=True)
    if (changed or gone) and writable:
        text = json.dumps(manifest, indent=1, sort_keys=True)
        try:
            atomic_write(folder / MANIFEST, lambda tmp: tmp.write_text(text))
        except OSError as exc:
            log.warning("cannot write the cache manifest in %s (%s)", folder, exc)
    return out
