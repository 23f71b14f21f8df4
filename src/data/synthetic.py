"""A small synthetic dataset in the exact H3.6M text format (99 comma-separated numbers with 7
decimals per line, LF endings), for tests and smoke runs. Only the 54 columns used on the real
data (§2.1) move, the other 45 are 0 (D = 54 as on H3.6M); the motion is smooth (per-action
frequencies, per-sequence phases, two harmonics, a little noise): a model can learn it."""

from __future__ import annotations

import io
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from src.data.archive import resolve_data_dir
from src.data.errors import DataError
from src.data.files import atomic_write
from src.data.h36m import H36MDataModule
from src.data.layout import H36M, H36M_ACTIONS, h36m_files

# The 54 used columns on H3.6M (protocol §2.1).
H36M_USED_COLUMNS: tuple[int, ...] = tuple(
    np.r_[0:10, 12:16, 21:25, 27:31, 36:48, 51:58, 60:63, 75:82, 84:87].tolist()
)
SYNTHETIC_ACTIONS = ("walking", "eating", "smoking")


def synthetic_motion(
    subject: int, action: str, subaction: int, raw_frames: int, seed: int = 0
) -> np.ndarray:
    """(raw_frames, 99) float64 frames of one synthetic sequence (see the module docstring)."""
    used = np.array(H36M_USED_COLUMNS)
    shape_rng = np.random.default_rng([seed, 0])  # per column, shared by all sequences
    amp = shape_rng.uniform(0.1, 0.5, used.size)
    offset = shape_rng.uniform(-0.5, 0.5, used.size)
    seq_rng = np.random.default_rng([seed, 1, subject, H36M_ACTIONS.index(action), subaction])
    phase1, phase2 = seq_rng.uniform(0, 2 * np.pi, (2, used.size))
    freq = 0.5 + 0.2 * (H36M_ACTIONS.index(action) % 8)  # Hz
    t = np.arange(raw_frames)[:, None] / 50  # seconds at the raw 50 Hz
    wave = np.sin(2 * np.pi * freq * t + phase1) + 0.3 * np.sin(4 * np.pi * freq * t + phase2)
    frames = np.zeros((raw_frames, H36M.n_columns))
    frames[:, used] = offset + amp * wave + seq_rng.normal(0.0, 0.005, (raw_frames, used.size))
    return frames


def write_synthetic_h36m(
    root: str | os.PathLike,
    subjects: Sequence[int] = (1, 5),
    actions: Sequence[str] = SYNTHETIC_ACTIONS,
    raw_frames: int = 400,
    seed: int = 0,
) -> list[Path]:
    """Write the synthetic files under ``root`` (the data_dir); return their paths. One that
    holds other frames (other ``raw_frames``, ``seed``) is replaced, the others left alone."""
    if raw_frames < 2:
        raise DataError(f"raw_frames must be >= 2, got {raw_frames}")
    root = Path(root)
    paths = []
    for entry in h36m_files(list(subjects), list(actions)):
        frames = synthetic_motion(entry.subject, entry.action, entry.index, raw_frames, seed)
        text = io.StringIO()
        np.savetxt(text, frames, fmt="%.7f", delimiter=",")
        data = text.getvalue().encode()
        path = root / entry.relpath
        paths.append(path)
        if not (path.is_file() and path.read_bytes() == data):
            atomic_write(path, lambda tmp, data=data: tmp.write_bytes(data))
    return paths


class SyntheticDataModule(H36MDataModule):
    """H3.6M pipeline on the synthetic files in ``<data_dir>/synthetic``; by default train
    subject 1, test subject 5, actions walking, eating, smoking (the archive is never needed)."""

    def __init__(
        self,
        data_dir: str | os.PathLike | None,
        raw_frames: int = 400,
        synthetic_seed: int = 0,
        **kwargs,
    ):
        kwargs = {"actions": SYNTHETIC_ACTIONS, "train_subjects": (1,), "test_subject": 5} | kwargs
        super().__init__(resolve_data_dir(data_dir) / "synthetic", **kwargs)
        self.raw_frames, self.synthetic_seed = raw_frames, synthetic_seed

    def _locate(self):
        # Always: files an earlier run wrote with another raw_frames or synthetic_seed must not
        # silently stand in for the ones these settings describe.
        subjects = [*([] if self._eval_only else self.train_subjects), self.test_subject]
        subjects += [] if self._eval_only or self.val_subject is None else [self.val_subject]
        write_synthetic_h36m(
            self.data_dir, subjects, self.actions, self.raw_frames, self.synthetic_seed
        )
        return super()._locate()
