"""The data layer on the real archives (MOTION_ARCHIVES), checked against protocol facts.

One extraction and cache per module (parsing all of H3.6M takes ~10-20 s); every test reuses it.
The copy described in the data README is partial; the tests check that this is reported exactly.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from src.data.cmu import CMUDataModule
from src.data.errors import DataError
from src.data.h36m import H36MDataModule
from src.data.layout import H36M, H36M_ACTIONS, h36m_files
from src.data.reader import load_sequences, read_motion_file
from src.data.synthetic import H36M_USED_COLUMNS
from src.data.windows import srnn_h36m_starts

pytestmark = pytest.mark.realdata

S5_MISSING = [
    "h3.6m/dataset/S5/directions_1.txt",
    "h3.6m/dataset/S5/discussion_1.txt",
    "h3.6m/dataset/S5/discussion_2.txt",
    "h3.6m/dataset/S5/sittingdown_1.txt",
    "h3.6m/dataset/S5/waiting_1.txt",
    "h3.6m/dataset/S5/waiting_2.txt",
]
H36M_ABSENT = {"discussion", "waiting", "directions", "sittingdown"}
# Protocol §2.2: CMU ignored columns.
CMU_IGNORED = [6, 7, 8, 14, *range(20, 27), 32, *range(38, 42), *range(60, 66), 69, 73, 74, 78, 79]
CMU_IGNORED += [81, 82, 83, *range(87, 93), 96, 100, 101, 105, 106, 108, 109, 110, 114, 115, 116]


@pytest.fixture(scope="module")
def archives() -> Path:
    folder = os.environ.get("MOTION_ARCHIVES")
    if not folder:
        pytest.skip("MOTION_ARCHIVES is unset: point it to the folder with h3.6m.zip/cmu_mocap.zip")
    return Path(folder)


@pytest.fixture(scope="module")
def data_dir(archives, tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("real_data")


@pytest.fixture(scope="module")
def h36m(archives, data_dir) -> H36MDataModule:
    dm = H36MDataModule(data_dir, archive_dir=archives, allow_partial=True)
    dm.prepare_data()
    dm.setup("fit")
    return dm


@pytest.fixture(scope="module")
def cmu(archives, data_dir) -> CMUDataModule:
    dm = CMUDataModule(data_dir, archive_dir=archives, allow_partial=True)
    dm.prepare_data()
    dm.setup("fit")
    return dm


# ---- H3.6M ----------------------------------------------------------------------------------


def test_h36m_54_used_dims_are_the_protocol_columns(h36m):
    assert (h36m.num_features, h36m.pose_dim) == (99, 54)
    assert h36m.normalizer.dim_used.tolist() == list(H36M_USED_COLUMNS)
    # Root translation / rotation stds quoted in protocol §1.1 (full data; ours is partial).
    expected = torch.tensor([3.3, 2.2, 6.7, 0.009, 0.013, 0.006])
    torch.testing.assert_close(h36m.normalizer.std[:6], expected, rtol=0.1, atol=0)


# Mao et al.'s hard-coded 48 dimensions (shared docs/hisrep.md §1).
HISREP_DIMS = [6, 7, 8, 9, 12, 13, 14, 15, 21, 22, 23, 24, 27, 28, 29, 30, *range(36, 48)]
HISREP_DIMS += [*range(51, 58), 60, 61, 62, *range(75, 82), 84, 85, 86]


def test_h36m_with_the_root_zeroed_uses_mao_et_als_48_dims_in_radians(h36m, archives, data_dir):
    """HisRep's data settings: the std rule over S1, S6-S9 with the root zeroed keeps exactly
    the authors' list, and normalize=false hands the model the raw angles."""
    dm = H36MDataModule(data_dir, archive_dir=archives, allow_partial=True, zero_root=True,
                        normalize=False, train_subjects=[1, 6, 7, 8, 9])  # fmt: skip
    dm.setup("fit")
    assert dm.normalizer.dim_used.tolist() == HISREP_DIMS
    w = dm.eval_windows[0]
    raw = torch.from_numpy(dm.raw_window(0)[: dm.observed_len])
    assert not raw[:, :6].any() and w == h36m.eval_windows[0]  # the same SRNN windows
    observed = dm.val_dataloader().dataset[0]["observed"]
    torch.testing.assert_close(observed, raw[:, HISREP_DIMS], rtol=0, atol=0)


def test_h36m_reference_angle_wrap_changes_only_the_root_translation(h36m, data_dir):
    """Protocol §2.3 (verified there): Li et al.'s wrap leaves the 54 used columns and every
    joint alone (no joint turns beyond 2pi) and shortens the root translation."""
    dm = H36MDataModule(data_dir, allow_partial=True, reference_angle_wrap=True)
    dm.prepare_data()
    dm.setup("fit")
    wrapped, plain = dm.normalizer, h36m.normalizer
    assert torch.equal(wrapped.dim_used, plain.dim_used)
    changed = (wrapped.mean != plain.mean) | (wrapped.std != plain.std)
    assert changed.nonzero().flatten().tolist() == [0, 1, 2]
    assert (wrapped.std[:3] < plain.std[:3] / 2).all()  # 3.3 2.2 6.7 -> 1.5 0.8 2.0


def test_h36m_raw_file_and_downsampling(h36m, data_dir):
    raw = read_motion_file(data_dir / "h3.6m/dataset/S5/walking_1.txt", 99)
    assert raw.shape == (3000, 99)  # protocol §1.1
    np.testing.assert_array_equal(h36m.test_sequence("walking", 0), raw[::2])


@pytest.mark.parametrize(
    ("action", "lengths", "starts"),
    [
        ("walking", (1500, 1261), [1087, 955, 1145, 332, 660, 304, 201, 54]),
        ("eating", (1638, 1166), [1426, 374, 1087, 156, 1329, 955, 1145, 332]),
        ("smoking", (1601, 1711), [1426, 1398, 1087, 1180, 1329, 955, 1145, 332]),
    ],
)
def test_srnn_windows_from_real_s5_lengths(h36m, action, lengths, starts):
    real = tuple(len(h36m.test_sequence(action, i)) for i in (0, 1))
    assert real == lengths
    assert [s for _, s in srnn_h36m_starts(*real)] == starts
    windows = [w for w in h36m.eval_windows if w.action == action]
    assert [(w.subaction, w.start) for w in windows] == list(zip([1, 2] * 4, starts, strict=True))


def test_h36m_partial_copy_report(h36m):
    assert set(S5_MISSING) <= set(h36m.missing_files)
    assert all(
        p.startswith(("h3.6m/dataset/S5/", "h3.6m/dataset/S7/", "h3.6m/dataset/S9/"))
        for p in h36m.missing_files
    )
    assert len(h36m.missing_files) == 20  # 6 S5 + 10 S7 + 4 S9 (data README)
    assert set(h36m.absent_actions) == H36M_ABSENT
    for action, reason in h36m.absent_actions.items():
        assert all(p in reason for p in S5_MISSING if f"/{action}_" in p)
    evaluated = [a for a in H36M_ACTIONS if a not in H36M_ABSENT]
    assert sorted({w.action for w in h36m.eval_windows}) == sorted(evaluated)
    assert len(h36m.eval_windows) == 11 * 8
    assert h36m.num_actions == 15  # labels keep all 15 actions


def test_h36m_full_protocol_refuses_partial_copy(h36m, data_dir):
    with pytest.raises(DataError) as err:
        H36MDataModule(data_dir).prepare_data()
    msg = str(err.value)
    assert all(p in msg for p in S5_MISSING)
    assert "MOTION_ALLOW_PARTIAL=true" in msg


def test_h36m_real_batches(h36m):
    batch = next(iter(h36m.train_dataloader()))
    assert batch["observed"].shape == (16, 50, 54) and batch["future"].shape == (16, 25, 54)
    assert torch.isfinite(batch["observed"]).all()
    val = next(iter(h36m.val_dataloader()))
    assert val["observed"].shape == (88, 50, 54)  # 88 windows < eval_batch_size 256


def test_cached_load_of_all_h36m_is_fast(h36m, data_dir):
    rels = [e.relpath for e in h36m_files([1, 5, 6, 7, 8, 9, 11], H36M_ACTIONS)]
    rels = [r for r in rels if (data_dir / r).is_file()]
    t0 = time.perf_counter()
    out = load_sequences(data_dir, H36M, rels)
    assert time.perf_counter() - t0 < 5.0
    assert len(out) == 190 and sum(len(a) for a in out.values()) == 427_673


# ---- CMU ------------------------------------------------------------------------------------


def test_cmu_70_used_dims_and_ignored_columns(cmu):
    assert (cmu.num_features, cmu.pose_dim) == (117, 70)
    ignored = torch.nonzero(~cmu.normalizer.used).flatten().tolist()
    assert ignored == CMU_IGNORED


def test_cmu_test_windows_and_partial_report(cmu):
    assert set(cmu.absent_actions) == {"basketball_signal", "directing_traffic"}
    assert cmu.untrained_actions == ["washwindow"]
    assert len(cmu.missing_files) == 10
    starts = {a: [w.start for w in cmu.eval_windows if w.action == a] for a in cmu.actions}
    assert len(cmu.test_sequence("running")) == 82 and len(cmu.test_sequence("walking")) == 180
    assert starts["running"] == [2, 6, 4, 3, 1, 3, 1, 4]  # protocol §3.2
    assert starts["walking"] == [2, 102, 47, 12, 51, 33, 43, 60]
    assert len(cmu.eval_windows) == 6 * 8


# ---- missing data ---------------------------------------------------------------------------


def test_missing_data_root_error(tmp_path, monkeypatch):
    empty = tmp_path / "no_archives"
    empty.mkdir()
    monkeypatch.setenv("MOTION_ARCHIVES", str(empty))
    for cls, name in ((H36MDataModule, "h3.6m.zip"), (CMUDataModule, "cmu_mocap.zip")):
        with pytest.raises(DataError) as err:
            cls(tmp_path / "data").prepare_data()
        msg = str(err.value)
        assert str(empty / name) in msg and "MOTION_ARCHIVES=" in msg and "data.archive=" in msg
