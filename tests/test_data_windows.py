"""Window start rules against the protocol's verified examples, and the training sampler."""

from __future__ import annotations

import itertools
from collections import Counter

import numpy as np
import pytest

from src.data import datasets as datasets_mod
from src.data.datasets import TrainWindowSampler
from src.data.errors import DataError
from src.data.windows import (
    TRAIN_START_LOW,
    cmu_test_starts,
    random_starts,
    srnn_h36m_starts,
    strided_starts,
)

# ---- SRNN (protocol §3.1) --------------------------------------------------------------------


@pytest.mark.parametrize(
    ("t1", "t2", "starts"),
    [
        (1500, 1261, [1087, 955, 1145, 332, 660, 304, 201, 54]),  # walking
        (1638, 1166, [1426, 374, 1087, 156, 1329, 955, 1145, 332]),  # eating
        (1601, 1711, [1426, 1398, 1087, 1180, 1329, 955, 1145, 332]),  # smoking
    ],
)
def test_srnn_starts_match_protocol_examples(t1, t2, starts):
    out = srnn_h36m_starts(t1, t2)
    assert out == list(zip([1, 2] * 4, starts, strict=True))


def test_srnn_uses_fresh_rng_per_call_and_ignores_global_state():
    np.random.seed(0)  # noqa: NPY002 (the point: global state must not matter)
    a = srnn_h36m_starts(1500, 1261)
    np.random.rand(10)  # noqa: NPY002
    assert srnn_h36m_starts(1500, 1261) == a
    assert srnn_h36m_starts(1500, 1261, seed=1) != a


def test_srnn_rejects_short_sequences():
    with pytest.raises(DataError, match="subaction 2 has 166 frames"):
        srnn_h36m_starts(1500, 166)


# ---- CMU (protocol §3.2) ---------------------------------------------------------------------


def test_cmu_starts_match_protocol_examples():
    assert cmu_test_starts(82) == [2, 6, 4, 3, 1, 3, 1, 4]  # running
    assert cmu_test_starts(180) == [2, 102, 47, 12, 51, 33, 43, 60]  # walking


def test_cmu_starts_depend_on_future_len_and_stay_in_range():
    short = cmu_test_starts(180, 50, 10)
    long = cmu_test_starts(180, 50, 100)
    assert short != long
    assert all(0 <= s < 180 - 150 for s in long)
    with pytest.raises(DataError, match="82 frames"):
        cmu_test_starts(82, 50, 100)


# ---- training ranges and project protocols ---------------------------------------------------


def test_training_ranges_follow_protocol():
    # H3.6M [16, n - (50 + T_out)), CMU [0, n - (50 + T_out)) (protocol §1.4, §1.5).
    assert TRAIN_START_LOW == {"h36m": 16, "cmu": 0}
    every = [(0, s) for s in range(16, 125)]
    assert strided_starts([200], 75, 1, TRAIN_START_LOW["h36m"]) == every
    assert strided_starts([82], 75, 1, TRAIN_START_LOW["cmu"]) == [(0, s) for s in range(7)]


def test_random_starts_are_seeded_bounded_and_skip_short_sequences():
    lengths = [100, 60, 300]  # sequence 1 cannot hold a 75-frame window from 16
    out = random_starts(lengths, n=500, window_len=75, low=16, seed=3)
    assert out == random_starts(lengths, n=500, window_len=75, low=16, seed=3)
    assert out != random_starts(lengths, n=500, window_len=75, low=16, seed=4)
    assert {s for s, _ in out} == {0, 2}
    assert all(16 <= start < lengths[s] - 75 for s, start in out)
    with pytest.raises(DataError, match="no sequence is long enough"):
        random_starts([60], n=1, window_len=75, low=16)


def test_strided_starts_enumerate_every_window():
    assert strided_starts([100, 90], window_len=75, stride=10, low=0) == [
        (0, 0),
        (0, 10),
        (0, 20),
        (1, 0),
        (1, 10),
    ]
    assert strided_starts([100], window_len=75, stride=5, low=16) == [(0, 16), (0, 21)]


# ---- TrainWindowSampler (protocol §1.4) ------------------------------------------------------


def _first(sampler, n):
    return list(itertools.islice(sampler, n))


def test_sampler_shapes_and_ranges():
    lengths = [200, 120, 90]
    s = TrainWindowSampler(lengths, window_len=75, low=16, batch_size=4)
    batches = _first(s, 50)
    assert all(len(b) == 4 for b in batches)
    pairs = [p for b in batches for p in b]
    assert {seq for seq, _ in pairs} == {0, 1}  # 90 - 75 = 15 < 16: sequence 2 never drawn
    assert all(16 <= start < lengths[seq] - 75 for seq, start in pairs)
    # With the regulariser a batch holds D's windows, then G's: two draws of batch_size.
    doubled = _first(TrainWindowSampler(lengths, window_len=75, low=16, batch_size=4, draws=2), 5)
    assert all(len(b) == 8 for b in doubled)


def test_sampler_is_uniform_over_sequences_not_lengths():
    # The reference draws the sequence key uniformly, then the start (protocol §1.4).
    s = TrainWindowSampler([100, 10_000], window_len=75, low=0, batch_size=100)
    counts = Counter(seq for b in _first(s, 40) for seq, _ in b)
    assert abs(counts[0] / 4000 - 0.5) < 0.04


def test_sampler_is_endless_reproducible_and_resumes_at_any_batch():
    make = lambda seed=0, start=0: TrainWindowSampler(  # noqa: E731
        [300, 250], window_len=75, low=16, batch_size=8, seed=seed, start=start
    )
    continuous = _first(make(), 2000)  # no end: the Trainer's max_steps stops it
    assert len(continuous) == 2000 and continuous[0] != continuous[1]
    assert _first(make(), 7) == continuous[:7]
    # A resume at batch k (the Trainer's global_step) draws what the continuous run drew.
    assert _first(make(start=1234), 3) == continuous[1234:1237]
    assert _first(make(seed=1), 3) != continuous[:3]


def test_sampler_ranks_draw_different_windows(monkeypatch):
    s = TrainWindowSampler([300, 250], window_len=75, low=16, batch_size=8)
    rank0 = _first(s, 5)  # rank 0 of DDP draws what a single process draws
    monkeypatch.setattr(datasets_mod, "_rank", lambda: 1)
    assert _first(s, 5) != rank0


def test_sampler_rejects_too_short_data():
    with pytest.raises(DataError, match="no training sequence is long enough"):
        TrainWindowSampler([80], window_len=75, low=16, batch_size=2)
