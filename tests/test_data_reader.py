"""Reader, cache and archive handling on small files written in the real text format."""

from __future__ import annotations

import errno
import os
import zipfile
from pathlib import Path

import numpy as np
import pytest

from src.data import archive as archive_mod
from src.data import reader as reader_mod
from src.data.archive import ensure_dataset, unpack_archive
from src.data.errors import DataError
from src.data.layout import CMU, H36M, h36m_files, missing_files
from src.data.reader import load_sequences, read_motion_file
from src.data.synthetic import write_synthetic_h36m


def _frames(n: int = 5, cols: int = 99, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-2, 2, (n, cols)).round(7)


def _write(path: Path, frames: np.ndarray, newline: str = "\n", trailing: bool = True) -> Path:
    lines = [",".join(f"{v:.7f}" for v in row) for row in frames]
    path.write_bytes((newline.join(lines) + (newline if trailing else "")).encode())
    return path


# ---- reader: valid input -------------------------------------------------------------------


@pytest.mark.parametrize("newline", ["\n", "\r\n"])
@pytest.mark.parametrize("trailing", [True, False])
def test_reads_lf_crlf_with_or_without_trailing_newline(tmp_path, newline, trailing):
    frames = _frames()
    out = read_motion_file(_write(tmp_path / "a.txt", frames, newline, trailing), 99)
    assert out.dtype == np.float32 and out.shape == (5, 99)
    np.testing.assert_array_equal(out, frames.astype(np.float32))


def test_blank_lines_and_bom_are_tolerated(tmp_path):
    frames = _frames(3, 4)
    text = "\ufeff" + "\n".join(",".join(map(str, r)) for r in frames) + "\n\n  \n"
    (tmp_path / "a.txt").write_text(text, encoding="utf-8")
    out = read_motion_file(tmp_path / "a.txt", 4)
    np.testing.assert_array_equal(out, frames.astype(np.float32))


# ---- reader: each error names the file, the line and a fix ---------------------------------


def test_missing_file(tmp_path):
    with pytest.raises(DataError, match="not found") as err:
        read_motion_file(tmp_path / "nope.txt", 99)
    assert str(tmp_path / "nope.txt") in str(err.value)


def test_empty_file(tmp_path):
    (tmp_path / "e.txt").write_text("")
    with pytest.raises(DataError, match="empty") as err:
        read_motion_file(tmp_path / "e.txt", 99)
    assert str(tmp_path / "e.txt") in str(err.value) and "fix:" in str(err.value)


def test_unreadable_file(tmp_path, monkeypatch):
    path = _write(tmp_path / "a.txt", _frames())

    def denied(fname, *args, **kwargs):  # as numpy's open fails without read permission
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(fname))

    # Simulated: root (CI) reads a chmod 0 file.
    monkeypatch.setattr(np, "loadtxt", denied)
    with pytest.raises(DataError, match=r"a\.txt: cannot read the file \(Permission denied\)"):
        read_motion_file(path, 99)


def test_blank_only_file(tmp_path):
    (tmp_path / "b.txt").write_text("\n\n\n")
    with pytest.raises(DataError, match="no data lines"):
        read_motion_file(tmp_path / "b.txt", 99)


def test_wrong_column_count_names_file_and_line(tmp_path):
    lines = [",".join(["0.1"] * 99)] * 2 + [",".join(["0.1"] * 98)] + [",".join(["0.1"] * 99)]
    path = tmp_path / "S5" / "walking_1.txt"
    path.parent.mkdir()
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError) as err:
        read_motion_file(path, 99)
    msg = str(err.value)
    assert f"{path}:3: expected 99 comma-separated numbers, found 98" in msg
    assert "fix:" in msg


def test_all_lines_short_is_reported_at_line_1(tmp_path):
    path = _write(tmp_path / "a.txt", _frames(4, 98))
    with pytest.raises(DataError, match=r"a\.txt:1: expected 99 comma-separated numbers, found 98"):
        read_motion_file(path, 99)


def test_trailing_comma_hint(tmp_path):
    (tmp_path / "a.txt").write_text("1,2,3,\n")
    with pytest.raises(DataError, match=r"a\.txt:1: expected 3 .* found 4 \(a trailing comma\?\)"):
        read_motion_file(tmp_path / "a.txt", 3)


def test_non_numeric_token_names_file_line_and_column(tmp_path):
    (tmp_path / "a.txt").write_text("1,2,3\n4,abc,6\n")
    with pytest.raises(DataError) as err:
        read_motion_file(tmp_path / "a.txt", 3)
    assert f"{tmp_path / 'a.txt'}:2: column 2 holds 'abc'" in str(err.value)


@pytest.mark.parametrize("bad", ["nan", "NaN", "inf", "-inf", "1e60"])
def test_nan_and_inf_are_rejected_with_line(tmp_path, bad):
    (tmp_path / "a.txt").write_text(f"1,2,3\n4,5,6\n7,8,9\n1,{bad},3\n")
    with pytest.raises(DataError) as err:
        read_motion_file(tmp_path / "a.txt", 3)
    msg = str(err.value)
    assert f"{tmp_path / 'a.txt'}:4: column 2" in msg and "NaN and infinite" in msg


# ---- layout ---------------------------------------------------------------------------------


def test_layout_lists_expected_files_and_reports_missing(tmp_path):
    entries = h36m_files([5], ["walking", "eating"])
    assert [e.relpath for e in entries] == [
        "h3.6m/dataset/S5/walking_1.txt",
        "h3.6m/dataset/S5/walking_2.txt",
        "h3.6m/dataset/S5/eating_1.txt",
        "h3.6m/dataset/S5/eating_2.txt",
    ]
    assert entries[1].key == "S5/walking_2" and entries[1].index == 2
    write_synthetic_h36m(tmp_path, subjects=(5,), actions=("walking",), raw_frames=10)
    assert missing_files(tmp_path, entries) == [
        "h3.6m/dataset/S5/eating_1.txt",
        "h3.6m/dataset/S5/eating_2.txt",
    ]


# ---- cache ----------------------------------------------------------------------------------


@pytest.fixture
def counted_parses(monkeypatch):
    """Record which files the cache actually parses."""
    calls: list[str] = []
    real = reader_mod.read_motion_file

    def spy(path, n_columns):
        calls.append(Path(path).name)
        return real(path, n_columns)

    monkeypatch.setattr(reader_mod, "read_motion_file", spy)
    return calls


def _synthetic(tmp_path):
    write_synthetic_h36m(tmp_path, subjects=(1,), actions=("walking", "eating"), raw_frames=20)
    return [e.relpath for e in h36m_files([1], ["walking", "eating"])]


def test_cache_hit_after_first_parse(tmp_path, counted_parses):
    rels = _synthetic(tmp_path)
    first = load_sequences(tmp_path, H36M, rels)
    assert len(counted_parses) == 4
    second = load_sequences(tmp_path, H36M, rels)
    assert len(counted_parses) == 4  # nothing re-parsed
    for rel in rels:
        np.testing.assert_array_equal(first[rel], second[rel])
        assert second[rel].shape == (20, 99)
    st = (tmp_path / rels[0]).stat()  # a cache file is named by its source's size and mtime
    name = f"h3.6m__dataset__S1__walking_1.{st.st_size}-{st.st_mtime_ns}.npy"
    assert (tmp_path / "cache/h36m" / name).is_file()


def test_changed_file_is_reparsed_alone(tmp_path, counted_parses):
    rels = _synthetic(tmp_path)
    load_sequences(tmp_path, H36M, rels)
    changed = tmp_path / rels[1]
    new = _frames(7)
    _write(changed, new)
    out = load_sequences(tmp_path, H36M, rels)
    assert counted_parses[4:] == [changed.name]
    np.testing.assert_array_equal(out[rels[1]], new.astype(np.float32))


def test_same_size_new_mtime_is_reparsed(tmp_path, counted_parses):
    rels = _synthetic(tmp_path)
    load_sequences(tmp_path, H36M, rels)
    st = (tmp_path / rels[0]).stat()
    os.utime(tmp_path / rels[0], ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
    load_sequences(tmp_path, H36M, rels)
    assert counted_parses[4:] == [Path(rels[0]).name]


def test_added_and_removed_files_update_their_entries(tmp_path, counted_parses):
    rels = _synthetic(tmp_path)
    load_sequences(tmp_path, H36M, rels[:2])
    load_sequences(tmp_path, H36M, rels)  # two new files
    assert len(counted_parses) == 4
    (tmp_path / rels[3]).unlink()
    load_sequences(tmp_path, H36M, rels[:3])
    assert len(counted_parses) == 4
    assert len(list((tmp_path / "cache/h36m").glob("*.npy"))) == 3
    _write(tmp_path / rels[0], _frames(7))  # a changed source: its earlier cache file goes
    load_sequences(tmp_path, H36M, rels[:3])
    assert len(list((tmp_path / "cache/h36m").glob("*.npy"))) == 3


def test_corrupt_cache_file_is_reparsed(tmp_path, counted_parses):
    rels = _synthetic(tmp_path)
    first = load_sequences(tmp_path, H36M, rels)
    npy = next((tmp_path / "cache/h36m").glob("*walking_1.*.npy"))
    npy.write_bytes(npy.read_bytes()[:100])  # truncated, as by a crash without atomic writes
    out = load_sequences(tmp_path, H36M, rels)
    assert counted_parses[4:] == ["walking_1.txt"]
    np.testing.assert_array_equal(out[rels[0]], first[rels[0]])
    npy.write_bytes(b"not a numpy file")
    load_sequences(tmp_path, H36M, rels)
    assert counted_parses[5:] == ["walking_1.txt"]  # no crash


def test_the_earlier_cache_layout_is_removed(tmp_path, counted_parses):
    rels = _synthetic(tmp_path)
    folder = tmp_path / "cache/h36m"
    folder.mkdir(parents=True)
    for name in ("manifest.json", "h3.6m__dataset__S1__walking_1.npy"):
        (folder / name).write_text("a cache file of the earlier layout")
    load_sequences(tmp_path, H36M, rels)
    assert len(counted_parses) == 4 and len(list(folder.iterdir())) == 4
    assert not (folder / "manifest.json").exists()


def test_cache_leaves_no_temp_files(tmp_path):
    rels = _synthetic(tmp_path)
    load_sequences(tmp_path, H36M, rels)
    assert not [p for p in (tmp_path / "cache/h36m").iterdir() if p.name.startswith(".")]


# ---- archive --------------------------------------------------------------------------------


def _zip_of(folder: Path, zip_path: Path, extra: dict[str, str] | None = None) -> Path:
    with zipfile.ZipFile(zip_path, "w") as zf:
        for p in sorted(folder.rglob("*.txt")):
            zf.write(p, p.relative_to(folder).as_posix())
        for name, text in (extra or {}).items():
            zf.writestr(name, text)
    return zip_path


def test_unpacks_archive_from_archive_dir(tmp_path, monkeypatch):
    monkeypatch.delenv("MOTION_ARCHIVES", raising=False)
    src = tmp_path / "src"
    write_synthetic_h36m(src, subjects=(5,), actions=("walking",), raw_frames=10)
    archives = tmp_path / "archives"
    archives.mkdir()
    _zip_of(src, archives / "h3.6m.zip", {"__MACOSX/x": "junk"})
    data = tmp_path / "data"
    assert ensure_dataset("h36m", data, archive_dir=archives) == data
    assert (data / "h3.6m/dataset/S5/walking_2.txt").read_bytes() == (
        src / "h3.6m/dataset/S5/walking_2.txt"
    ).read_bytes()
    assert sorted(p.name for p in data.iterdir()) == ["h3.6m"]  # no temp dir, no junk


def test_archive_found_through_env_var(tmp_path, monkeypatch):
    src = tmp_path / "src"
    write_synthetic_h36m(src, subjects=(5,), actions=("walking",), raw_frames=10)
    (tmp_path / "arch").mkdir()
    _zip_of(src, tmp_path / "arch" / "h3.6m.zip")
    monkeypatch.setenv("MOTION_ARCHIVES", str(tmp_path / "arch"))
    ensure_dataset("h36m", tmp_path / "data")
    assert (tmp_path / "data/h3.6m/dataset/S5/walking_1.txt").is_file()


@pytest.mark.parametrize("bad", ["../evil.txt", "h3.6m/../../evil.txt", "/abs/h3.6m/x.txt"])
def test_path_traversal_is_refused(tmp_path, bad):
    zip_path = tmp_path / "h3.6m.zip"
    with zipfile.ZipFile(zip_path, "w") as zf:
        zf.writestr("h3.6m/dataset/S5/walking_1.txt", "0\n")
        zf.writestr(bad, "pwned")
    with pytest.raises(DataError, match="unsafe member path"):
        unpack_archive(zip_path, tmp_path / "data", "h36m")
    assert not (tmp_path / "evil.txt").exists()
    assert not (tmp_path / "data" / "h3.6m").exists()


def test_interrupted_unpack_is_not_mistaken_for_data(tmp_path, monkeypatch):
    monkeypatch.delenv("MOTION_ARCHIVES", raising=False)
    data = tmp_path / "data"
    # What a killed unpack leaves behind: a temp dir of a dead process.
    stale = data / ".h3.6m.unpacking-999999999" / "h3.6m" / "dataset" / "S5"
    stale.mkdir(parents=True)
    (stale / "walking_1.txt").write_text("0.1,0.2\n")
    with pytest.raises(DataError, match="h36m data not found"):
        ensure_dataset("h36m", data)
    src = tmp_path / "src"
    write_synthetic_h36m(src, subjects=(5,), actions=("walking",), raw_frames=10)
    ensure_dataset("h36m", data, archive=_zip_of(src, tmp_path / "h3.6m.zip"))
    assert sorted(p.name for p in data.iterdir()) == ["h3.6m"]  # stale temp removed


def test_wrong_archive_is_reported(tmp_path):
    src = tmp_path / "src"
    write_synthetic_h36m(src, subjects=(5,), actions=("walking",), raw_frames=10)
    zip_path = _zip_of(src, tmp_path / "cmu_mocap.zip")
    with pytest.raises(DataError, match="holds no cmu_mocap/ folder"):
        ensure_dataset("cmu", tmp_path / "data", archive=zip_path)
    (tmp_path / "x.zip").write_text("not a zip")
    with pytest.raises(DataError, match="not a zip archive"):
        ensure_dataset("h36m", tmp_path / "data", archive=tmp_path / "x.zip")
    (tmp_path / "cut.zip").write_bytes(zip_path.read_bytes()[:-100])  # a download cut short
    with pytest.raises(DataError, match=r"cut.zip: an incomplete zip archive .*interrupted"):
        ensure_dataset("h36m", tmp_path / "data", archive=tmp_path / "cut.zip")


def test_unwritable_data_dir_is_a_data_error_naming_it(tmp_path):
    """A data_dir that cannot be created (here a file is in the way; also a read-only folder)."""
    src = tmp_path / "src"
    write_synthetic_h36m(src, subjects=(5,), actions=("walking",), raw_frames=10)
    zip_path = _zip_of(src, tmp_path / "h3.6m.zip")
    (tmp_path / "taken").write_text("a user's file")
    with pytest.raises(DataError, match="cannot unpack h3.6m.zip into .*writable folder"):
        ensure_dataset("h36m", tmp_path / "taken" / "data", archive=zip_path)
    assert (tmp_path / "taken").read_text() == "a user's file"


def test_disk_full_while_unpacking_is_a_data_error(tmp_path, monkeypatch):
    src = tmp_path / "src"
    write_synthetic_h36m(src, subjects=(5,), actions=("walking",), raw_frames=10)
    zip_path = _zip_of(src, tmp_path / "h3.6m.zip")

    def disk_full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(archive_mod.shutil, "copyfileobj", disk_full)
    data = tmp_path / "data"
    with pytest.raises(DataError, match="cannot unpack h3.6m.zip .*No space left on device"):
        ensure_dataset("h36m", data, archive=zip_path)
    assert list(data.iterdir()) == []  # the temp folder went


def test_unreadable_archive_is_not_called_damaged(tmp_path, monkeypatch):
    src = tmp_path / "src"
    write_synthetic_h36m(src, subjects=(5,), actions=("walking",), raw_frames=10)
    zip_path = _zip_of(src, tmp_path / "h3.6m.zip")

    def denied(path, *args, **kwargs):  # as open() fails for a user without read permission
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(path))

    # Shadows the builtin in the archive module only: root (CI) reads a chmod 0 file.
    monkeypatch.setattr(archive_mod, "open", denied, raising=False)
    with pytest.raises(DataError, match="cannot read .*h3.6m.zip.*Permission denied"):
        ensure_dataset("h36m", tmp_path / "data", archive=zip_path)


@pytest.mark.parametrize("spec", [H36M, CMU])
def test_nothing_found_says_what_to_download_and_where(tmp_path, monkeypatch, spec):
    monkeypatch.delenv("MOTION_ARCHIVES", raising=False)
    with pytest.raises(DataError) as err:
        ensure_dataset(spec.name, tmp_path / "data")
    msg = str(err.value)
    for needle in (
        spec.archive_name,
        spec.url,
        "MOTION_ARCHIVES=",
        "data.archive=",
        "MOTION_DATA_DIR",
    ):
        assert needle in msg, needle
    assert str(tmp_path / "data") in msg


def test_missing_explicit_archive_path(tmp_path):
    with pytest.raises(DataError, match="does not exist"):
        ensure_dataset("h36m", tmp_path / "data", archive=tmp_path / "nope.zip")
    # A folder that exists but does not hold the archive: the message names the missing zip.
    with pytest.raises(DataError, match=f"{tmp_path / 'h3.6m.zip'} does not exist"):
        ensure_dataset("h36m", tmp_path / "data", archive=tmp_path)


@pytest.fixture
def http_folder(tmp_path, monkeypatch):
    """Serve ``tmp_path / "www"`` on localhost (the only network use in these tests)."""
    import functools
    import http.server
    import threading

    for var in ("http_proxy", "HTTP_PROXY", "https_proxy", "HTTPS_PROXY", "all_proxy", "ALL_PROXY"):
        monkeypatch.delenv(var, raising=False)
    www = tmp_path / "www"
    www.mkdir()
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(www))
    handler.log_message = lambda *a, **k: None
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield www, f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()


def test_url_archive_is_downloaded_into_data_dir_then_unpacked(tmp_path, http_folder):
    www, base = http_folder
    src = tmp_path / "src"
    write_synthetic_h36m(src, subjects=(5,), actions=("walking",), raw_frames=10)
    _zip_of(src, www / "h3.6m.zip")
    (www / "page.html").write_text("<html>not found</html>")
    data = tmp_path / "data"
    with pytest.raises(DataError, match="did not return a zip archive"):
        ensure_dataset("h36m", data, archive=f"{base}/page.html")
    with pytest.raises(DataError, match="could not download"):
        ensure_dataset("h36m", data, archive=f"{base}/missing.zip")
    ensure_dataset("h36m", data, archive=f"{base}/h3.6m.zip")
    assert (data / "h3.6m.zip").read_bytes() == (www / "h3.6m.zip").read_bytes()
    assert (data / "h3.6m/dataset/S5/walking_1.txt").is_file()
    assert sorted(p.name for p in data.iterdir()) == ["h3.6m", "h3.6m.zip"]
