"""DataModules end to end on synthetic files in the real text format (no real data needed)."""

from __future__ import annotations

import itertools
import zipfile
from pathlib import Path

import lightning as L
import numpy as np
import pytest
import torch
from torch import nn

from src.data.cmu import CMUDataModule
from src.data.errors import DataError
from src.data.h36m import H36MDataModule
from src.data.layout import h36m_files
from src.data.normalization import Normalizer
from src.data.reader import read_motion_file
from src.data.synthetic import H36M_USED_COLUMNS, SyntheticDataModule, write_synthetic_h36m
from src.data.windows import cmu_test_starts, srnn_h36m_starts
from tests import objects
from tests.conftest import run_in_one_process

SMALL = dict(batch_size=4, eval_batch_size=5)


@pytest.fixture
def synthetic(tmp_path):
    dm = SyntheticDataModule(tmp_path, **SMALL)
    dm.prepare_data()
    dm.setup("fit")
    return dm


# ---- synthetic H3.6M --------------------------------------------------------------------------


def test_synthetic_files_are_in_the_real_format(tmp_path):
    (path,) = [p for p in write_synthetic_h36m(tmp_path, (1,), ("walking",)) if "_1" in p.name]
    assert path.relative_to(tmp_path).as_posix() == "h3.6m/dataset/S1/walking_1.txt"
    raw = path.read_bytes()
    assert b"\r" not in raw and raw.endswith(b"\n")
    lines = raw.decode().splitlines()
    assert len(lines) == 400
    fields = lines[0].split(",")
    assert len(fields) == 99 and all(len(f.split(".")[1]) == 7 for f in fields)
    ignored = [c for c in range(99) if c not in H36M_USED_COLUMNS]
    assert all(line.split(",")[c] == "0.0000000" for line in lines for c in ignored)


def test_synthetic_settings_apply_over_files_of_an_earlier_run(tmp_path):
    def lengths_and_mean(**kwargs):
        dm = SyntheticDataModule(tmp_path, actions=["walking"], **SMALL, **kwargs)
        dm.prepare_data()
        dm.setup("fit")
        return dm._train_lengths, dm.normalizer.mean.clone()

    default = lengths_and_mean()
    longer = lengths_and_mean(raw_frames=600)
    assert longer[0] == [300, 300] and default[0] == [200, 200]
    reseeded = lengths_and_mean(synthetic_seed=1)
    assert reseeded[0] == default[0] and not torch.equal(reseeded[1], default[1])
    again = lengths_and_mean()
    assert again[0] == default[0] and torch.equal(again[1], default[1])


def test_synthetic_module_attributes(synthetic):
    dm = synthetic
    assert (dm.dataset_name, dm.conv_padding, dm.frame_ms) == ("h36m", "same", 40)
    assert (dm.pose_dim, dm.num_features) == (54, 99)
    assert dm.normalizer.dim_used.tolist() == list(H36M_USED_COLUMNS)
    assert dm.actions == ["walking", "eating", "smoking"] and dm.num_actions == 3
    assert (dm.observed_len, dm.future_len, dm.discriminator_windows) == (50, 25, False)
    assert dm.absent_actions == {} and dm.missing_files == []
    assert dm.test_sequence("eating", 1).shape == (200, 99)  # 400 raw frames -> even frames


def test_normalizer_uses_raw_50hz_training_frames(synthetic, tmp_path):
    entries = h36m_files([1], synthetic.actions)
    raw = [read_motion_file(tmp_path / "synthetic" / e.relpath, 99) for e in entries]
    expected = Normalizer.from_sequences(raw)
    assert torch.equal(synthetic.normalizer.mean, expected.mean)
    downsampled = Normalizer.from_sequences([r[::2] for r in raw])
    assert not torch.allclose(synthetic.normalizer.mean, downsampled.mean, atol=1e-6, rtol=0)


def test_test_sequence_is_downsampled_raw(synthetic, tmp_path):
    raw = read_motion_file(tmp_path / "synthetic/h3.6m/dataset/S5/smoking_2.txt", 99)
    np.testing.assert_array_equal(synthetic.test_sequence("smoking", 1), raw[::2])
    with pytest.raises(DataError, match="greeting has no test sequence 0: 0 are loaded"):
        synthetic.test_sequence("greeting")
    with pytest.raises(DataError, match="smoking has no test sequence 2: 2 are loaded"):
        synthetic.test_sequence("smoking", 2)


def test_srnn_eval_windows_and_their_content(synthetic):
    dm = synthetic
    assert len(dm.eval_windows) == 24
    for action in dm.actions:
        ws = [w for w in dm.eval_windows if w.action == action]
        expected = srnn_h36m_starts(200, 200)
        assert [(w.subaction, w.start) for w in ws] == expected
        assert [w.sequence for w in ws] == [f"S5/{action}_{s}" for s, _ in expected]
    batches = list(dm.val_dataloader())
    assert [len(b["window"]) for b in batches] == [5, 5, 5, 5, 4]
    batch = {k: torch.cat([b[k] for b in batches]) for k in batches[0]}
    assert batch["window"].tolist() == list(range(24))
    assert batch["observed"].shape == (24, 50, 54) and batch["future"].shape == (24, 25, 54)
    assert batch["observed"].dtype == torch.float32 and batch["action"].dtype == torch.long
    for i, w in enumerate(dm.eval_windows):
        seq = torch.from_numpy(dm.test_sequence(w.action, w.subaction - 1))
        window = dm.normalizer.normalize(seq[w.start : w.start + 75])
        assert torch.equal(batch["observed"][i], window[:50])
        assert torch.equal(batch["future"][i], window[50:])
        assert batch["action"][i] == dm.actions.index(w.action)
    assert len(list(dm.test_dataloader())) == len(batches)


def test_train_batches(synthetic):
    dm = synthetic
    b = next(iter(dm.train_dataloader()))
    assert set(b) == {"observed", "future", "action"}
    assert b["observed"].shape == (4, 50, 54) and b["future"].shape == (4, 25, 54)
    assert b["action"].dtype == torch.long and set(b["action"].tolist()) <= {0, 1, 2}
    # With the regulariser D's windows ride along under "d": as many, other ones.
    dm.discriminator_windows = True
    b = next(iter(dm.train_dataloader()))
    assert set(b) == {"observed", "future", "action", "d"} and set(b["d"]) == set(b) - {"d"}
    assert b["d"]["observed"].shape == b["observed"].shape == (4, 50, 54)
    assert not torch.equal(b["d"]["observed"], b["observed"])


def test_mao_et_als_data_settings_root_zeroed_raw_radians_ten_frames_to_train(tmp_path):
    """zero_root: the root's 6 columns are 0 in every frame, so the std rule drops them (54 -> 48
    used); normalize=false: the model sees the used columns as they are, and unnormalize gives
    the rest back as the training mean; train_future_len: training windows of 50 + 10 frames
    while the evaluation keeps 25."""
    dm = SyntheticDataModule(
        tmp_path, zero_root=True, normalize=False, train_future_len=10, **SMALL
    )
    dm.prepare_data()
    dm.setup("fit")
    used = [c for c in H36M_USED_COLUMNS if c >= 6]
    assert dm.normalizer.dim_used.tolist() == used and dm.pose_dim == 48
    raw = torch.from_numpy(dm.raw_window(0))
    assert not raw[:, :6].any()
    item = dm.val_dataloader().dataset[0]
    torch.testing.assert_close(item["observed"], raw[:50, used], rtol=0, atol=0)
    full = dm.normalizer.unnormalize(item["future"])
    torch.testing.assert_close(full[:, used], raw[50:, used], rtol=0, atol=0)
    unused = [c for c in range(99) if c not in used]
    assert torch.equal(full[:, unused], dm.normalizer.mean[unused].expand(25, -1))
    batch = next(iter(dm.train_dataloader()))
    assert batch["observed"].shape == (4, 50, 48) and batch["future"].shape == (4, 10, 48)
    assert next(iter(dm.val_dataloader()))["future"].shape == (5, 25, 48)


def test_a_validation_subject_is_what_training_validates_on_and_src_eval_is_not(tmp_path):
    """val_subject=11: training validates on every val_stride-th window of S11's files (all
    configured actions); the test windows stay the test loader's, and an evaluation (stage
    validate, as src.eval) validates on them."""
    dm = SyntheticDataModule(tmp_path, val_subject=11, val_stride=7, **SMALL)
    dm.prepare_data()
    dm.setup("fit")
    val = dm.val_dataloader().dataset
    lengths = [len(f[::2]) for f in (read_motion_file(tmp_path / "synthetic" / e.relpath, 99)
                                     for e in h36m_files([11], dm.actions))]  # fmt: skip
    assert len(val) == sum(len(range(0, n - 75, 7)) for n in lengths) > 0
    first = read_motion_file(tmp_path / "synthetic" / h36m_files([11], dm.actions)[0].relpath, 99)
    want = dm.normalizer.normalize(torch.from_numpy(first[::2][:50].copy()))
    torch.testing.assert_close(val[0]["observed"], want, rtol=0, atol=0)
    assert len(dm.test_dataloader().dataset) == len(dm.eval_windows) == 24
    assert dm.test_dataloader().dataset is not val

    evaluating = SyntheticDataModule(tmp_path, val_subject=11, **SMALL)
    evaluating.setup("validate")
    assert len(evaluating.val_dataloader().dataset) == len(evaluating.eval_windows) == 24


def test_batches_are_pinned_only_for_a_gpu_trainer(synthetic):
    from types import SimpleNamespace

    assert not synthetic.train_dataloader().pin_memory  # no trainer attached
    for device, pinned in (("cpu", False), ("cuda", True)):
        root = SimpleNamespace(type=device)
        strategy = SimpleNamespace(root_device=root)
        synthetic.trainer = SimpleNamespace(strategy=strategy, global_step=0)
        assert synthetic.train_dataloader().pin_memory is pinned
        assert synthetic.val_dataloader().pin_memory is pinned


@pytest.mark.parametrize("protocol", ["random", "strided"])
def test_other_eval_protocols(tmp_path, protocol):
    dm = SyntheticDataModule(
        tmp_path, eval_protocol=protocol, eval_windows_per_action=7, eval_stride=20, **SMALL
    )
    dm.setup()
    per_action = 7 if protocol == "random" else 2 * len(range(16, 200 - 75, 20))
    assert len(dm.eval_windows) == 3 * per_action
    assert all(16 <= w.start < 200 - 75 for w in dm.eval_windows)


def test_setup_without_prepare_and_twice(tmp_path):
    dm = SyntheticDataModule(tmp_path, **SMALL)
    with pytest.raises(DataError, match="call prepare_data"):
        _ = dm.pose_dim
    dm.setup("test")
    normalizer = dm.normalizer
    dm.setup("fit")
    assert dm.normalizer is normalizer


def test_single_action_module(tmp_path):
    dm = SyntheticDataModule(tmp_path, actions="eating", **SMALL)
    dm.setup()
    assert dm.actions == ["eating"] and dm.num_actions == 1 and len(dm.eval_windows) == 8
    batches = itertools.islice(dm.train_dataloader(), 20)
    assert {b["action"].unique().item() for b in batches} == {0}


# ---- partial copies -------------------------------------------------------------------------


def test_partial_copy_full_protocol_raises_listing_files(tmp_path):
    SyntheticDataModule(tmp_path).prepare_data()
    gone = ["h3.6m/dataset/S5/eating_2.txt", "h3.6m/dataset/S1/smoking_1.txt"]
    root = tmp_path / "synthetic"
    dm = H36MDataModule(root, actions=["walking", "eating", "smoking"], train_subjects=(1,))
    for rel in gone:
        (root / rel).unlink()
    with pytest.raises(DataError) as err:
        dm.prepare_data()
    msg = str(err.value)
    assert all(rel in msg for rel in gone) and "MOTION_ALLOW_PARTIAL=true" in msg


def test_partial_copy_allowed_reports_absent_actions(tmp_path, caplog):
    SyntheticDataModule(tmp_path).prepare_data()
    root = tmp_path / "synthetic"
    (root / "h3.6m/dataset/S5/eating_2.txt").unlink()
    (root / "h3.6m/dataset/S1/smoking_1.txt").unlink()
    dm = H36MDataModule(
        root, actions="walking,eating,smoking", train_subjects=[1], allow_partial=True, **SMALL
    )
    with caplog.at_level("WARNING"):
        dm.prepare_data()
        dm.setup()
    assert "S5/eating_2.txt" in caplog.text
    assert list(dm.absent_actions) == ["eating"]
    assert "h3.6m/dataset/S5/eating_2.txt" in dm.absent_actions["eating"]
    assert sorted(dm.missing_files) == [
        "h3.6m/dataset/S1/smoking_1.txt",
        "h3.6m/dataset/S5/eating_2.txt",
    ]
    assert {w.action for w in dm.eval_windows} == {"walking", "smoking"}
    assert dm.actions == ["walking", "eating", "smoking"]  # labels unchanged
    with pytest.raises(DataError, match="test file is missing"):
        dm.test_sequence("eating", 1)


def test_missing_files_are_counted_by_kind_and_the_message_says_what_is_done(tmp_path, caplog):
    """Issue 40: training reported 20 missing files "training on what exists", evaluating a
    checkpoint on the same copy 6 with the same words. Each says what it counts and does."""
    SyntheticDataModule(tmp_path).prepare_data()
    root = tmp_path / "synthetic"
    (root / "h3.6m/dataset/S5/eating_2.txt").unlink()  # a test file
    (root / "h3.6m/dataset/S1/smoking_1.txt").unlink()  # a training file
    kwargs = {"actions": "walking,eating,smoking", "train_subjects": [1], "allow_partial": True}
    messages, trained = {}, None
    for stage in ("fit", "evaluate a checkpoint", "evaluate a baseline"):
        dm = H36MDataModule(root, **kwargs, **SMALL)
        if stage == "evaluate a checkpoint":  # the statistics a checkpoint carries
            dm.set_normalizer(trained.normalizer)
        caplog.clear()
        with caplog.at_level("WARNING"):
            dm.prepare_data()
            dm.setup("fit" if stage == "fit" else "validate")
        (messages[stage],) = [r.getMessage() for r in caplog.records if "missing" in r.msg]
        trained = trained or dm
    assert "2 h36m file(s) are missing" in messages["fit"]
    assert "(1 training, 1 test); training on the files that exist" in messages["fit"]
    checkpoint = messages["evaluate a checkpoint"]
    assert "1 h36m test file(s) are missing" in checkpoint and "training on" not in checkpoint
    assert "the checkpoint holds the normalisation); evaluating with the files" in checkpoint
    baseline = messages["evaluate a baseline"]
    assert "(1 training, 1 test); normalising and evaluating with the files" in baseline


def test_missing_files_are_one_line_with_their_count_and_the_flag_that_lists_them(tmp_path):
    """Every command printed a partial copy's whole list (20 lines on the real H3.6M copy):
    one line counts them and names the flag that lists them; with it, the command lists every
    one (once), without it none."""
    SyntheticDataModule(tmp_path).prepare_data()
    root = tmp_path / "synthetic"
    gone = ["h3.6m/dataset/S1/smoking_1.txt", "h3.6m/dataset/S1/smoking_2.txt"]
    for rel in gone:
        (root / rel).unlink()
    args = ["model=zero_velocity", "data=h36m", "data.actions=[walking,eating,smoking]"]
    args += ["data.train_subjects=[1]", "paths.allow_partial=true", "trainer=cpu"]
    plain, listed = run_in_one_process(
        ["src.eval", *args], ["src.eval", *args, "hydra.verbose=src.data.base"],
        data_dir=root, log_dir=tmp_path / "out",
    )  # fmt: skip
    for proc in plain, listed:
        assert proc.returncode == 0, proc.stderr[-3000:]
    (line,) = [x for x in plain.stdout.splitlines() if "are missing under" in x]
    assert "2 h36m file(s)" in line and "hydra.verbose=src.data.base" in line, line
    assert not any(rel in plain.stdout + plain.stderr for rel in gone)
    assert all(listed.stdout.count(rel) == 1 for rel in gone), listed.stdout[-3000:]


def test_missing_data_root(tmp_path, monkeypatch):
    monkeypatch.delenv("MOTION_ARCHIVES", raising=False)
    dm = H36MDataModule(tmp_path / "empty")
    for step in (dm.prepare_data, dm.setup):
        with pytest.raises(DataError, match="h3.6m.zip") as err:
            step()
        assert "http://www.cs.stanford.edu/people/ashesh/h3.6m.zip" in str(err.value)


def test_module_unpacks_an_archive(tmp_path, monkeypatch):
    monkeypatch.delenv("MOTION_ARCHIVES", raising=False)
    src = tmp_path / "src"
    write_synthetic_h36m(src, subjects=(1, 5), actions=("walking",))
    zip_path = tmp_path / "h3.6m.zip"
    with zipfile.ZipFile(zip_path, "w") as zf:
        for p in src.rglob("*.txt"):
            zf.write(p, p.relative_to(src).as_posix())
    dm = H36MDataModule(tmp_path / "data", archive=zip_path, actions="walking", train_subjects=[1])
    dm.prepare_data()
    dm.setup()
    assert dm.pose_dim == 54 and len(dm.eval_windows) == 8
    assert len(list((tmp_path / "data/cache/h36m").glob("*.npy"))) == 4


# ---- argument validation --------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "pattern"),
    [
        ({"actions": "jogging"}, r"unknown h36m action.*'jogging'.*walking, eating, smoking"),
        ({"eval_protocol": "best"}, r"eval_protocol 'best'; valid: srnn, random, strided"),
        ({"future_len": 0}, r"future_len must be an integer >= 1"),
        ({"observed_len": -1}, r"observed_len must be an integer >= 1"),
        ({"batch_size": 0}, r"batch_size"),
        ({"train_subjects": (1, 2)}, r"unknown H3.6M subject.*\[2\]"),
        ({"train_subjects": (1, 5)}, r"test_subject=5 is also a training subject"),
        ({"future_len": 101}, r"srnn test windows reserve 150 frames"),
        ({"eval_seed": 2**32}, r"eval_seed must be below 2\*\*32"),
        ({"train_future_len": 0}, r"train_future_len must be an integer >= 1"),
        ({"val_subject": 1}, r"val_subject=1 is also a training or the test subject"),
        ({"val_subject": 5}, r"val_subject=5 is also a training or the test subject"),
        ({"val_subject": 3}, r"data.val_subject: unknown H3.6M subject"),
        ({"val_subject": 11, "val_stride": 0}, r"val_stride must be an integer >= 1"),
        (
            {"train_future_len": 10, "discriminator_windows": True},
            r"train_future_len=10 with the adversarial regulariser.*adversarial=none",
        ),
    ],
)
def test_invalid_arguments(tmp_path, kwargs, pattern):
    with pytest.raises(DataError, match=pattern):
        H36MDataModule(tmp_path, **kwargs)


def test_long_horizon_allowed_with_random_protocol(tmp_path):
    dm = H36MDataModule(tmp_path, future_len=101, eval_protocol="random")
    assert dm.future_len == 101


def test_cmu_action_validation(tmp_path):
    with pytest.raises(DataError, match="valid actions are 'all' or any of: basketball,"):
        CMUDataModule(tmp_path, actions=["walking", "eating"])


# ---- CMU on hand-written files --------------------------------------------------------------


def _write_cmu(root: Path, actions=("running", "walking"), raw=220, skip=()):
    rng = np.random.default_rng(0)
    for split, count in (("train", 5), ("test", 1)):
        for action in actions:
            for k in range(1, count + 1):
                rel = f"cmu_mocap/{split}/{action}/{action}_{k}.txt"
                if rel in skip:
                    continue
                x = np.zeros((raw + 2 * k, 117))
                x[:, :70] = np.cumsum(rng.normal(0, 0.05, (raw + 2 * k, 70)), axis=0)
                (root / rel).parent.mkdir(parents=True, exist_ok=True)
                np.savetxt(root / rel, x, fmt="%.7f", delimiter=",")
    (root / "cmu_mocap/train/walking_extra").mkdir(parents=True)  # ignored folder
    (root / "cmu_mocap/train/walking_extra/walking_extra_1.txt").write_text("garbage\n")


def test_cmu_module(tmp_path):
    _write_cmu(tmp_path)
    dm = CMUDataModule(tmp_path, actions=["walking", "running"], future_len=10, **SMALL)
    dm.prepare_data()
    dm.setup()
    assert (dm.dataset_name, dm.conv_padding, dm.frame_ms) == ("cmu", "valid", 40)
    assert (dm.num_features, dm.pose_dim) == (117, 70)
    assert dm.actions == ["running", "walking"]
    starts = cmu_test_starts(111, 50, 10)  # test file: 222 raw frames -> 111
    assert [w.start for w in dm.eval_windows] == starts + starts
    assert {w.sequence for w in dm.eval_windows} == {
        "test/running/running_1",
        "test/walking/walking_1",
    }
    b = next(iter(dm.train_dataloader()))
    assert b["observed"].shape == (4, 50, 70) and b["future"].shape == (4, 10, 70)


def test_cmu_partial(tmp_path):
    _write_cmu(tmp_path, skip=("cmu_mocap/test/running/running_1.txt",))
    with pytest.raises(DataError, match="cmu_mocap/test/running/running_1.txt"):
        CMUDataModule(tmp_path, actions=["walking", "running"]).prepare_data()
    dm = CMUDataModule(tmp_path, actions=["walking", "running"], allow_partial=True)
    dm.setup()
    assert list(dm.absent_actions) == ["running"] and len(dm.eval_windows) == 8


# ---- Lightning integration ------------------------------------------------------------------


class _Recorder(L.LightningModule):
    """Records the first value of every observed window it is trained on."""

    def __init__(self):
        super().__init__()
        self.layer = nn.Linear(1, 1)
        self.seen: dict[int, list[torch.Tensor]] = {}

    def training_step(self, batch, batch_idx):
        self.seen[self.global_step] = batch["observed"][:, 0, 0].clone()
        return self.layer(torch.ones(1, 1)).sum()

    def configure_optimizers(self):
        return torch.optim.SGD(self.parameters(), lr=0.0)


def _fit(data_dir, max_steps, ckpt_path=None, save_to=None):
    dm = SyntheticDataModule(data_dir, **SMALL)
    model = _Recorder()
    trainer = L.Trainer(
        max_steps=max_steps,
        accelerator="cpu",
        devices=1,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        limit_val_batches=0,
    )
    trainer.fit(model, datamodule=dm, ckpt_path=ckpt_path)
    if save_to:
        trainer.save_checkpoint(save_to)
    return model.seen


@pytest.mark.filterwarnings("ignore:You passed in a `val_dataloader`")
def test_a_plain_trainer_draws_new_batches_repeats_them_and_resumes_at_its_step(tmp_path):
    """The training loader is endless, batch k drawn from (seed, k): a plain Trainer's max_steps
    ends it, a rerun draws the same batches, and a fit resumed from a checkpoint at step 3
    continues with batch 3, as the uninterrupted fit drew it."""
    run1 = _fit(tmp_path, 5)
    run2 = _fit(tmp_path, 5)
    assert sorted(run1) == [0, 1, 2, 3, 4] and run1[0].shape == (4,)
    assert not torch.equal(run1[0], run1[1])
    assert all(torch.equal(run1[k], run2[k]) for k in run1)
    ckpt = tmp_path / "step3.ckpt"
    _fit(tmp_path, 3, save_to=ckpt)
    resumed = _fit(tmp_path, 5, ckpt_path=ckpt)
    assert sorted(resumed) == [3, 4] and all(torch.equal(resumed[k], run1[k]) for k in resumed)


def test_the_reference_angle_wrap_of_the_config_reaches_the_statistics(tmp_path):
    """data.reference_angle_wrap=true gives Li et al.'s statistics (protocol §2.3): the root
    translation, as long as the real one, wrapped; every joint column as without it."""
    SyntheticDataModule(tmp_path).prepare_data()
    root = tmp_path / "synthetic"
    for path in root.glob("h3.6m/dataset/S*/*.txt"):
        frames = read_motion_file(path, 99)
        frames[:, 0] += np.linspace(0.0, 12.0, len(frames))  # walks 12 units, beyond 2pi
        np.savetxt(path, frames, fmt="%.7f", delimiter=",")
    small = ["data.actions=[walking,eating,smoking]", "data.train_subjects=[1]"]
    built = {}
    for wrap in (True, False):
        overrides = ["data=h36m", f"data.reference_angle_wrap={wrap}", *small]
        cfg = objects.compose(overrides, tmp_path / f"out{wrap}", root)
        built[wrap] = objects.datamodule(cfg.data).normalizer
    assert bool(built[True].wrap) and not bool(built[False].wrap)
    assert torch.equal(built[True].dim_used, built[False].dim_used)
    assert built[True].mean[0] < built[False].mean[0] - 1.0  # the long steps come back short
    assert torch.equal(built[True].mean[3:], built[False].mean[3:])
