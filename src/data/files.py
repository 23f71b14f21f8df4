"""The two ways this project writes where something else may be: a file written whole or not at
all, and a new folder no other process can take. Every writer in src/ goes through these."""

from __future__ import annotations

import itertools
import os
from collections.abc import Callable
from contextlib import suppress
from pathlib import Path


def atomic_write(path: str | os.PathLike, write: Callable[[Path], object]) -> Path:
    """`write(tmp)` a temporary file beside `path` (same suffix, for np.save), renamed over `path`:
    a reader, or a run killed mid-write, sees the old file or the new one, never half of one."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp-{os.getpid()}{path.suffix}")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def claim_folder(base: str | os.PathLike) -> Path:
    """Create (with its parents) and return `base`, or `base-1`, `base-2`, ... when taken: mkdir
    succeeds in one process only, so runs started in the same second get folders of their own."""
    base = Path(base)
    base.parent.mkdir(parents=True, exist_ok=True)
    for n in itertools.count():
        candidate = base.with_name(f"{base.name}-{n}") if n else base
        with suppress(FileExistsError):
            candidate.mkdir()
            return candidate
