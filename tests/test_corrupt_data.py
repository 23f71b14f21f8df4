"""Corrupted motion files, generated at random: `read_motion_file` either returns a valid array
(finite float32, the right number of columns) or raises the project's DataError naming the file
and, for a bad line, its number. Never a numpy or unicode traceback, never NaN in the data."""

from __future__ import annotations

import io
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from src.data.errors import DataError
from src.data.reader import read_motion_file

N_COLUMNS = 6
N_ROWS = 5
BAD_VALUES = ["1e300", "-1e300", "inf", "-inf", "nan", "NaN", "3.5e38", "1e39", "Infinity", ""]
# Tokens Python's float() takes but no motion file holds: a damaged file, not a number.
ODD_NUMBERS = ["1_0", "\u0661", "0x1f", "1d5", "--1", "1e", "."]
ASCII_NUMBER = re.compile(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?")


def _valid_lines(seed: int) -> list[str]:
    rng = np.random.default_rng(seed)
    return [",".join(f"{v:.7f}" for v in row) for row in rng.normal(0, 1, (N_ROWS, N_COLUMNS))]


# One corruption = (kind, where, payload); `where` is reduced modulo the size it applies to.
corruption = st.one_of(
    st.tuples(st.just("truncate"), st.integers(0, 10_000), st.just(b"")),
    st.tuples(st.just("garbage"), st.integers(0, 10_000), st.binary(min_size=1, max_size=8)),
    st.tuples(st.just("delimiter"), st.integers(0, 100), st.sampled_from([";", " ", "\t", "|"])),
    st.tuples(st.just("drop_column"), st.integers(0, 10_000), st.just(b"")),
    st.tuples(st.just("extra_column"), st.integers(0, 100), st.just(b"")),
    st.tuples(st.just("value"), st.integers(0, 10_000), st.sampled_from(BAD_VALUES + ODD_NUMBERS)),
    st.tuples(st.just("blank_lines"), st.integers(0, 100), st.sampled_from(["", "  ", "\t", "\r"])),
)


def _corrupt(lines: list[str], steps) -> bytes:
    lines = list(lines)
    data = None
    for kind, where, payload in steps:
        if data is not None:  # byte-level corruption happened; keep working on bytes
            lines = data.decode("utf-8", errors="surrogateescape").split("\n")
        i = where % max(len(lines), 1)
        if kind == "delimiter" and lines:
            lines[i] = lines[i].replace(",", payload)
        elif kind == "drop_column" and lines:
            fields = lines[i].split(",")
            del fields[where % len(fields)]
            lines[i] = ",".join(fields)
        elif kind == "extra_column" and lines:
            lines[i] += ",0.5"
        elif kind == "value" and lines:
            fields = lines[i].split(",")
            fields[where % len(fields)] = payload
            lines[i] = ",".join(fields)
        elif kind == "blank_lines":
            lines.insert(i, payload)
        text = "\n".join(lines).encode("utf-8", errors="surrogateescape")
        if kind == "truncate":
            data = text[: where % (len(text) + 1)]
        elif kind == "garbage":
            pos = where % (len(text) + 1)
            data = text[:pos] + payload + text[pos:]
        else:
            data = text
    return data if data is not None else "\n".join(lines).encode()


def _strict_parse(data: bytes) -> np.ndarray | None:
    """The frames a strict reader takes from `data`: UTF-8, blank lines skipped, exactly
    N_COLUMNS plain decimal numbers per line, all finite in float32; None if anything is off."""
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return None
    rows = []
    for line in io.StringIO(text, newline=None):  # \n, \r\n and \r end lines, as open() does
        fields = [f.strip() for f in line.strip().split(",")]
        if fields == [""]:
            continue
        if len(fields) != N_COLUMNS or not all(ASCII_NUMBER.fullmatch(f) for f in fields):
            return None
        rows.append([float(f) for f in fields])
    frames = np.array(rows, dtype=np.float64)
    if not rows or not (np.abs(frames) <= np.finfo(np.float32).max).all():
        return None
    return frames.astype(np.float32)


@settings(
    max_examples=100,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(seed=st.integers(0, 3), steps=st.lists(corruption, min_size=1, max_size=4))
def test_corrupted_file_loads_cleanly_or_raises_data_error(tmp_path, seed, steps):
    path = tmp_path / "S1" / "walking_1.txt"
    path.parent.mkdir(exist_ok=True)
    data = _corrupt(_valid_lines(seed), steps)
    path.write_bytes(data)
    try:
        frames = read_motion_file(path, N_COLUMNS)
    except DataError as err:
        message = str(err)
        assert str(path) in message
        # A bad line is named by number; only an empty file has no line to name.
        assert re.search(rf"{re.escape(str(path))}:\d+: ", message) or (
            "empty" in message or "no data lines" in message
        ), message
        return
    assert frames.dtype == np.float32
    assert frames.ndim == 2 and frames.shape[1] == N_COLUMNS and frames.shape[0] >= 1
    assert np.isfinite(frames).all()
    # Whatever loads is exactly what the text says: nothing dropped, altered or invented.
    expected = _strict_parse(data)
    assert expected is not None, f"accepted a damaged file: {data!r}"
    np.testing.assert_array_equal(frames, expected)


def test_untouched_file_round_trips(tmp_path):
    """The generator's base file is valid, so the property above is not vacuous."""
    path = tmp_path / "ok.txt"
    lines = _valid_lines(0)
    path.write_text("\n".join(lines) + "\n")
    frames = read_motion_file(path, N_COLUMNS)
    expected = np.array([[float(v) for v in line.split(",")] for line in lines], np.float32)
    np.testing.assert_array_equal(frames, expected)


@pytest.mark.parametrize(
    ("payload", "line"),
    [
        (b"\xff\xfe\x00garbage", 3),  # binary junk (not UTF-8) in line 3
        (b"1e300", 2),  # finite in float64, inf in float32
    ],
)
def test_specific_corruptions_name_the_line(tmp_path, payload, line):
    lines = [s.encode() for s in _valid_lines(1)]
    lines[line - 1] = payload + b"," + lines[line - 1].split(b",", 1)[1]
    path = tmp_path / "bad.txt"
    path.write_bytes(b"\n".join(lines))
    with pytest.raises(DataError, match=rf"bad.txt:{line}: column 1"):
        read_motion_file(path, N_COLUMNS)
