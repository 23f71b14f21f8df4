"""Parse each motion text file once and keep a binary copy under ``<data_dir>/cache/<dataset>/``:
one ``.npy`` per file plus ``manifest.json`` with each source's size and ``mtime_ns``, so a
changed, new or vanished source updates just its own entry. Writes are atomic; a cache file that
does not read back with the right shape is parsed again."""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Sequence
from contextlib import suppress
from pathlib import Path

import numpy as np

from src.data.files import atomic_write
from src.data.layout import DatasetSpec
from src.data.reader import read_motion_file

log = logging.getLogger(__name__)

CACHE_VERSION = 1
MANIFEST = "manifest.json"


def cache_dir(data_dir: str | os.PathLike, spec: DatasetSpec) -> Path:
    return Path(data_dir) / "cache" / spec.name


def load_sequences(
    data_dir: str | os.PathLike, spec: DatasetSpec, relpaths: Sequence[str]
) -> dict[str, np.ndarray]:
    """Raw (50 Hz, all columns) float32 arrays of ``relpaths`` (relative to ``data_dir``), from
    the cache where it is valid, else parsed and cached (parsed every time, with a warning, if
    the cache folder is not writable)."""
    data_dir = Path(data_dir)
    folder = cache_dir(data_dir, spec)
    manifest = _read_manifest(folder, spec)
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


def _read_manifest(folder: Path, spec: DatasetSpec) -> dict:
    with suppress(OSError, ValueError, LookupError, TypeError, AttributeError):  # start afresh
        manifest = json.loads((folder / MANIFEST).read_text())
        files = manifest["files"]
        same = (manifest["version"], manifest["n_columns"]) == (CACHE_VERSION, spec.n_columns)
        if same and all({"size", "mtime_ns", "frames", "npy"} <= e.keys() for e in files.values()):
            return manifest
    return dict(version=CACHE_VERSION, dataset=spec.name, n_columns=spec.n_columns, files={})
