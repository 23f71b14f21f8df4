"""Find, download (only when asked) and unpack a dataset archive; report missing files. Tried in
order: the unpacked folder under ``data_dir``; ``archive`` (a zip, its folder, or an http(s) URL,
downloaded into ``data_dir``); ``<archive_dir>/<name>.zip``, ``$MOTION_ARCHIVES/<name>.zip``,
``<data_dir>/<name>.zip``. Unpacking goes through a temporary folder renamed into place (an
interrupted unpack never looks like data) and refuses absolute, ``..`` and symlink members."""

from __future__ import annotations

import logging
import os
import shutil
import stat
import urllib.request
import zipfile
import zlib
from pathlib import Path, PurePosixPath

from src.data.errors import DataError
from src.data.files import atomic_write
from src.data.layout import SPECS, DatasetSpec

log = logging.getLogger(__name__)

ARCHIVES_ENV = "MOTION_ARCHIVES"
DATA_DIR_ENV = "MOTION_DATA_DIR"


def resolve_data_dir(data_dir: str | os.PathLike | None) -> Path:
    return Path(data_dir or os.environ.get(DATA_DIR_ENV) or "data").expanduser()


def ensure_dataset(
    dataset: str | DatasetSpec, data_dir: str | os.PathLike | None, archive=None, archive_dir=None
) -> Path:
    """Unpack the dataset under ``data_dir`` unless it is there; return ``data_dir``. ``archive``:
    a zip's path, its folder or URL; ``archive_dir``: a folder that may hold the zip."""
    spec = SPECS[dataset] if isinstance(dataset, str) else dataset
    data_dir = resolve_data_dir(data_dir)
    if not (data_dir / spec.marker).is_dir():
        zip_path = _find_archive(spec, data_dir, archive, archive_dir)
        log.info("unpacking %s into %s", zip_path, data_dir)
        unpack_archive(zip_path, data_dir, spec)
    return data_dir


def _find_archive(spec: DatasetSpec, data_dir: Path, archive, archive_dir) -> Path:
    if archive and str(archive).startswith(("http://", "https://")):
        return download(str(archive), data_dir / spec.archive_name)
    if archive:
        path = Path(archive).expanduser()
        path = path / spec.archive_name if path.is_dir() else path
        if not path.is_file():
            # Name the file looked for: a folder given as data.archive exists, its zip does not.
            raise DataError(
                f"data.archive={archive}: {path} does not exist (fix: point data.archive to "
                f"{spec.archive_name} or to the folder that holds it; {_how_to_get(spec)})"
            )
        return path

    searched, absent = [], []
    env = os.environ.get(ARCHIVES_ENV)
    for folder, name in ((archive_dir, "data.archive_dir"), (env, ARCHIVES_ENV), (data_dir, None)):
        if not folder:
            continue
        candidate = Path(folder).expanduser() / spec.archive_name
        if str(candidate) in searched:  # data.archive_dir defaults to $MOTION_ARCHIVES
            continue
        searched.append(str(candidate))
        if candidate.is_file():
            return candidate
        if name is not None and not candidate.parent.is_dir():
            name = ARCHIVES_ENV if str(folder) == str(env) else name
            absent.append(f"{name}={folder}: that folder does not exist")

    raise DataError(
        f"{spec.name} data not found: there is no folder {data_dir / spec.marker} and no archive "
        f"(looked for {', '.join(searched)}){''.join(f'; {a}' for a in absent)}.\n"
        f"Fix: {_how_to_get(spec)}, then either\n"
        f"  - set {ARCHIVES_ENV}=<the folder holding {spec.archive_name}>, or\n"
        f"  - pass data.archive=<path to {spec.archive_name}, or its http(s) URL to download it>.\n"
        f"It is unpacked into data.data_dir (now {data_dir}; env {DATA_DIR_ENV} sets the "
        f"default). An already unpacked copy is used if {data_dir / spec.marker} exists."
    )


def _how_to_get(spec: DatasetSpec) -> str:
    return f"download {spec.source} ({spec.url})"


def download(url: str, dest: Path) -> Path:
    """Download ``url`` to ``dest`` (atomically); reuse ``dest`` if already there."""
    if dest.is_file() and zipfile.is_zipfile(dest):
        return dest
    log.warning("downloading %s to %s (data.archive is a URL)", url, dest)
    fix = (
        f"fix: download it by hand, pass data.archive=<its path> or set {ARCHIVES_ENV}=<its folder>"
    )

    def fetch(part: Path) -> None:
        try:
            with urllib.request.urlopen(url, timeout=60) as response, open(part, "wb") as out:
                shutil.copyfileobj(response, out, 1 << 20)
        except OSError as exc:  # URLError and HTTPError are OSErrors
            raise DataError(f"could not download {url}: {exc} ({fix})") from None
        if not zipfile.is_zipfile(part):
            raise DataError(f"{url} did not return a zip archive (an error page?) ({fix})")

    return atomic_write(dest, fetch)


def unpack_archive(archive: str | os.PathLike, data_dir: str | os.PathLike, dataset) -> None:
    """Safely unpack the dataset folder of ``archive`` into ``data_dir`` (temp dir + rename)."""
    spec = SPECS[dataset] if isinstance(dataset, str) else dataset
    archive, data_dir = Path(archive), Path(data_dir)
    # is_zipfile() answers False for a file it cannot open, which would blame the archive.
    try:
        with open(archive, "rb") as fh:
            head = fh.read(4)
    except OSError as exc:
        raise DataError(
            f"cannot read {archive}: {exc} (fix: make it readable by this user, or point "
            "data.archive at a readable copy)"
        ) from None
    if not zipfile.is_zipfile(archive):
        # A zip's directory is at its end: a download cut short starts like a zip but has none.
        what = (
            "an incomplete zip archive (its end is missing: an interrupted download or copy?)"
            if head == b"PK\x03\x04"
            else "not a zip archive"
        )
        raise DataError(
            f"{archive}: {what} (fix: use {spec.archive_name} as distributed; {_how_to_get(spec)})"
        )
    tmp = data_dir / f".{spec.root}.unpacking-{os.getpid()}"
    try:
        data_dir.mkdir(parents=True, exist_ok=True)
        for old in data_dir.glob(f".{spec.root}.unpacking-*"):  # left by killed unpacks
            try:
                os.kill(int(old.name.rsplit("-", 1)[1]), 0)
            except (ValueError, ProcessLookupError):  # its process is gone
                shutil.rmtree(old, ignore_errors=True)
            except PermissionError:
                pass  # a live process of another user
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir()
    except OSError as exc:  # read-only, not a folder, or a file in the way
        raise DataError(
            f"cannot unpack {archive.name} into {data_dir}: {exc} (fix: point data.data_dir, or "
            f"{DATA_DIR_ENV}, at a writable folder)"
        ) from None
    try:
        _extract(archive, spec, tmp)
        if not (tmp / spec.marker).is_dir():
            raise DataError(
                f"{archive}: holds no {spec.marker}/ folder, so it is not the {spec.name} archive "
                f"(fix: {_how_to_get(spec)})"
            )
        target = data_dir / spec.root
        try:
            os.rename(tmp / spec.root, target)
        except OSError:
            if not (data_dir / spec.marker).is_dir():
                raise DataError(
                    f"cannot move the unpacked data to {target}: the folder exists but holds no "
                    f"{spec.marker}/ (fix: delete {target} and run again)"
                ) from None
            # else another process finished unpacking first; its copy is as good as ours
    except OSError as exc:  # disk full or over quota while writing the members
        raise DataError(
            f"cannot unpack {archive.name} into {data_dir}: {exc}; nothing was unpacked (fix: "
            f"free space there, or point data.data_dir, or {DATA_DIR_ENV}, at a writable folder "
            "with room for it)"
        ) from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _extract(archive: Path, spec: DatasetSpec, tmp: Path) -> None:
    """Write the dataset members of ``archive`` under ``tmp``; name a damaged one in a DataError."""
    member = None  # the member last read, named when the archive turns out damaged
    try:
        with zipfile.ZipFile(archive) as zf:
            for info in zf.infolist():
                name = info.filename.replace("\\", "/")
                parts = PurePosixPath(name).parts
                absolute = name.startswith("/") or (parts and ":" in parts[0])
                if absolute or ".." in parts or stat.S_ISLNK(info.external_attr >> 16):
                    raise DataError(
                        f"{archive}: unsafe member path {name!r} (absolute, with '..' or a "
                        "symbolic link); refusing to unpack (fix: use the archive as distributed)"
                    )
                # Members outside the dataset folder (__MACOSX/, a README) are skipped.
                if spec.root not in parts or info.is_dir():
                    continue
                member = info.filename
                info.filename = "/".join(parts[parts.index(spec.root) :])  # written there
                zf.extract(info, tmp)
    except (zipfile.BadZipFile, zlib.error, EOFError) as err:
        where = f"member {member!r}" if member else "its directory"
        raise DataError(
            f"{archive} is damaged: {where} does not read back as stored ({err}); nothing was "
            f"unpacked. Fix: download {spec.archive_name} again ({spec.url}) and check it with "
            f"`unzip -t {archive.name}` (or compare its sha256 with the MANIFEST your copy came "
            "with)."
        ) from None
