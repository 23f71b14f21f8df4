"""The test windows as plain arrays for models outside the project (`src.export_windows` writes
them, `src.scoring` checks predictions against them), and their fingerprint."""

from __future__ import annotations

import hashlib
from collections.abc import Iterable

import numpy as np

from src.data.base import MotionDataModule, window_ids


def windows_sha256(ids: Iterable[str], frames: Iterable[np.ndarray]) -> str:
    """SHA-256 over each window's id and its observed + future frames (float32, C order), in
    the protocol's order: equal for equal windows, whoever computes it from whatever copy."""
    digest = hashlib.sha256()
    for name, window in zip(ids, frames, strict=True):
        digest.update(name.encode())
        digest.update(np.ascontiguousarray(window, dtype=np.float32).tobytes())
    return digest.hexdigest()


def data_sha256(dm: MotionDataModule) -> str:
    """`windows_sha256` of a set-up datamodule's evaluation windows."""
    ids = window_ids(dm.eval_windows)
    return windows_sha256(ids, (dm.raw_window(i) for i in range(len(ids))))


def window_arrays(dm: MotionDataModule, dataset: str) -> dict[str, np.ndarray]:
    """A set-up datamodule's test windows as plain arrays for outside models (`src.export_windows`
    writes them, `src.scoring` checks predictions against them), in the protocol's order:
    - ``observed`` (N, observed_len, F), ``future`` (N, future_len, F): raw exp-map frames,
      float32, downsampled as everywhere (§1.3); F = 99 on H3.6M, 117 on CMU;
    - ``action``, ``window_id`` (`window_ids`): (N,) strings; 0-d metadata: ``dataset`` (the data
      config's name: ``synthetic`` is not H3.6M), ``protocol``, ``fps`` (25, on CMU too, as the
      tables' horizons assume, protocol §1.5), ``data_sha256`` (`windows_sha256`)."""
    frames = np.stack([dm.raw_window(i) for i in range(len(dm.eval_windows))])
    ids = window_ids(dm.eval_windows)
    return {
        "observed": frames[:, : dm.observed_len],
        "future": frames[:, dm.observed_len :],
        "action": np.array([w.action for w in dm.eval_windows]),
        "window_id": np.array(ids),
        "dataset": np.array(dataset),
        "protocol": np.array(dm.eval_protocol),
        "fps": np.array(1000.0 / dm.frame_ms),
        "data_sha256": np.array(windows_sha256(ids, frames)),
    }
