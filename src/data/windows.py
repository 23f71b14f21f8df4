"""Start frames of training and evaluation windows (downsampled frames, §1.3) from sequence
lengths. Training starts, as in the reference code, lie in [16, n - (50 + T_out)) on H3.6M (§1.4)
and [0, n - (50 + T_out)) on CMU (§1.5); the ``random`` and ``strided`` protocols use these too."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from src.data.errors import DataError

SRNN_SEED = 1234567890
TRAIN_START_LOW = {"h36m": 16, "cmu": 0}
SRNN_PREFIX, SRNN_SUFFIX = 50, 100  # the SRNN rule always reserves 150 frames (§3.1)


def srnn_h36m_starts(
    len_sub1: int, len_sub2: int, n: int = 8, seed: int = SRNN_SEED
) -> list[tuple[int, int]]:
    """(subaction, start) of the SRNN test windows of one H3.6M action (protocol §3.1): a fresh
    RandomState(seed) per call; draw i uses subaction (i % 2) + 1 and randint(16, T_sub - 150),
    so the starts do not depend on T_out."""
    lengths = {1: len_sub1, 2: len_sub2}
    for sub, length in lengths.items():
        if length - SRNN_PREFIX - SRNN_SUFFIX <= 16:
            raise DataError(
                f"subaction {sub} has {length} frames; the SRNN test windows need more than "
                f"{16 + SRNN_PREFIX + SRNN_SUFFIX} (fix: use the complete test files)"
            )
    rng = np.random.RandomState(seed)
    subs = [i % 2 + 1 for i in range(n)]
    return [(s, int(rng.randint(16, lengths[s] - SRNN_PREFIX - SRNN_SUFFIX))) for s in subs]


def cmu_test_starts(
    length: int, observed_len: int = 50, future_len: int = 25, n: int = 8, seed: int = SRNN_SEED
) -> list[int]:
    """Starts of the 8 CMU test windows of one action's test file (protocol §3.2): a fresh
    RandomState(seed) per call, randint(0, n - (observed_len + future_len)), so unlike H3.6M
    the starts depend on T_out."""
    high = length - (observed_len + future_len)
    if high <= 0:
        raise DataError(
            f"the test sequence has {length} frames, fewer than the "
            f"{observed_len + future_len + 1} that a {observed_len}+{future_len} window needs"
        )
    rng = np.random.RandomState(seed)
    return [int(rng.randint(0, high)) for _ in range(n)]


def random_starts(
    lengths: Sequence[int], n: int, window_len: int, low: int = 0, seed: int = SRNN_SEED
) -> list[tuple[int, int]]:
    """``n`` (sequence index, start) pairs: sequence uniform among those long enough, start
    uniform in [low, length - window_len). A fresh RandomState(seed) per call, as in §3.1."""
    eligible = [i for i, t in enumerate(lengths) if t - window_len > low]
    if not eligible:
        raise DataError(
            f"no sequence is long enough for a {window_len}-frame window starting at >= {low} "
            f"(lengths {list(lengths)})"
        )
    rng = np.random.RandomState(seed)
    out = []
    for _ in range(n):
        seq = eligible[rng.randint(len(eligible))]
        out.append((seq, int(rng.randint(low, lengths[seq] - window_len))))
    return out


def strided_starts(
    lengths: Sequence[int], window_len: int, stride: int, low: int = 0
) -> list[tuple[int, int]]:
    return [(i, s) for i, t in enumerate(lengths) for s in range(low, t - window_len, stride)]
