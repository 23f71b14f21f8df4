"""Every path that reads raw frames reads the same ones, at 25 fps (issue 41, point 4).

On the real archives (MOTION_ARCHIVES; skipped without them), for one action of each dataset,
the frames of one window are taken straight from the archive's text file, rows 0, 2, 4, ...
(protocol 1.3: 50 Hz files used at 25 fps, on CMU as on H3.6M), and compared with what each
path of the project gives for that window:

- the training loader (a window it draws is 75 consecutive even rows of a training file,
  its start in the training range of protocol 1.4 / 1.5);
- the evaluation windows src.eval scores (protocol 3.1 / 3.2);
- `python -m src.export_windows` (its frames and its stated frame rate);
- src.visualize (the joint positions it draws for the ground truth and zero-velocity);
- MotionForecaster of a checkpoint: it states 25 fps, and frames at 50 fps with fps=50
  (batch and stream) predict what the 25 fps frames do, which is what src.eval predicts.

Set MOTION_DATA_DIR to reuse the unpacked archives between runs.
"""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from tests import objects

pytestmark = pytest.mark.realdata

WINDOW, OBSERVED = 75, 50
ARCHIVE = {"h36m": "h3.6m.zip", "cmu": "cmu_mocap.zip"}
# One action each; H3.6M trains on subject 1 only, to keep the test short.
CASES = {
    "h36m": ("walking", ["data.train_subjects=[1]"], 16),
    "cmu": ("basketball", [], 0),
}


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    yield from objects.one_thread()


def archive_rows(archives: Path, dataset: str, key: str) -> np.ndarray:
    """All raw rows (50 Hz) of the archive's text file whose name ends in `key`.txt."""
    with zipfile.ZipFile(archives / ARCHIVE[dataset]) as zf:
        (member,) = [n for n in zf.namelist() if n.endswith(f"/{key}.txt")]
        return np.loadtxt(io.BytesIO(zf.read(member)), delimiter=",", dtype=np.float32)


def training_files(archives: Path, dataset: str, action: str) -> list[str]:
    """Keys of the training files of `action` the cases use."""
    with zipfile.ZipFile(archives / ARCHIVE[dataset]) as zf:
        names = zf.namelist()
    if dataset == "h36m":
        return [f"S1/{action}_{i}" for i in (1, 2)]
    prefix = f"cmu_mocap/train/{action}/"
    return [n.removeprefix("cmu_mocap/")[:-4] for n in names if n.startswith(prefix)]


@pytest.fixture(scope="module", params=sorted(CASES))
def case(request, archives, real_data_dir, tmp_path_factory):
    dataset = request.param
    action, extra, low = CASES[dataset]
    data = [f"data={dataset}", f"data.actions=[{action}]", "data.allow_partial=true", *extra]
    out = tmp_path_factory.mktemp(dataset)

    def compose(name: str, *overrides: str):
        return objects.compose([*overrides], out / name, real_data_dir, name=name)

    return {
        "dataset": dataset,
        "action": action,
        "low": low,
        "data": data,
        "out": out,
        "compose": compose,
        "archives": archives,
    }


def first_window(dm, action: str) -> int:
    """Index of the first evaluation window of `action` that starts after frame 0 (so that the
    50 fps rows before it exist)."""
    return next(i for i, w in enumerate(dm.eval_windows) if w.action == action and w.start > 0)


def test_training_windows_are_consecutive_even_rows_of_a_training_file(case):
    cfg = case["compose"]("train", *case["data"], "data.batch_size=4")
    dm = objects.datamodule(cfg.data)
    batch = next(iter(dm.train_dataloader()))
    window = torch.cat([batch["observed"][0], batch["future"][0]])  # normalised
    found = []
    for key in training_files(case["archives"], case["dataset"], case["action"]):
        frames = dm.normalizer.normalize(
            torch.from_numpy(archive_rows(case["archives"], case["dataset"], key)[::2].copy())
        )
        for start in range(len(frames) - WINDOW + 1):
            if torch.allclose(frames[start : start + WINDOW], window, rtol=0, atol=1e-6):
                found.append((key, start, len(frames)))
    assert len(found) == 1, f"the drawn window is at {found}: not one window of even rows"
    (key, start, length) = found[0]
    assert case["low"] <= start < length - WINDOW, (key, start, length)


def test_evaluation_export_and_visualisation_read_the_archives_even_rows(case):
    dataset, action = case["dataset"], case["action"]
    cfg = case["compose"]("eval", "model=zero_velocity", *case["data"])
    dm, module = objects.evaluation_objects(cfg)
    index = first_window(dm, action)
    w = dm.eval_windows[index]
    truth = archive_rows(case["archives"], dataset, w.sequence)[::2][w.start : w.start + WINDOW]
    assert truth.shape[0] == WINDOW

    # What src.eval scores: the window's frames, normalised.
    item = dm.val_dataloader().dataset[index]
    scored = torch.cat([item["observed"], item["future"]])
    torch.testing.assert_close(scored, dm.normalizer.normalize(torch.from_numpy(truth)))

    # What src.export_windows writes: the raw frames, at 25 fps.
    export_cfg = case["compose"](
        "export_windows", *case["data"], "protocol=srnn", f"out={case['out'] / 'w.npz'}"
    )
    with np.load(objects.export_windows(export_cfg)) as npz:
        ids = list(npz["window_id"])
        k = ids.index(f"{w.sequence}@{w.start}")
        np.testing.assert_array_equal(npz["observed"][k], truth[:OBSERVED])
        np.testing.assert_array_equal(npz["future"][k], truth[OBSERVED:])
        assert float(npz["fps"]) == 25.0

    # What src.visualize draws: the window's frames (ignored columns at the training mean, as
    # every unnormalised frame, protocol 2.2), and zero-velocity's repeated frame 49.
    drawn, positions = objects.visualised_positions(dm, module, index)
    used = dm.normalizer.used.numpy()
    shown = truth.copy()
    shown[:, ~used] = dm.normalizer.mean.numpy()[~used]
    expected = positions(torch.from_numpy(shown), _skeleton(dataset))
    np.testing.assert_allclose(drawn["ground truth"], expected, atol=1e-4)
    still = np.concatenate([shown[:OBSERVED], np.repeat(shown[OBSERVED - 1 : OBSERVED], 25, 0)])
    expected_still = positions(torch.from_numpy(still), _skeleton(dataset))
    (zero_velocity,) = [v for name, v in drawn.items() if name != "ground truth"]
    np.testing.assert_allclose(zero_velocity, expected_still, atol=1e-4)


def _skeleton(dataset: str):
    from src.metrics.kinematics import Skeleton

    return Skeleton.load(dataset)


def test_the_forecaster_reads_frames_at_25_fps_as_evaluation_does(case):
    dataset, action = case["dataset"], case["action"]
    cfg = case["compose"](
        "train", *case["data"], "model=conv_s2s", "model.net.nf=2", "model.net.d_z=8",
        "adversarial=none", "iterations=1", "val_every=1", "checkpoint_every=0",
        "media_every=0", "progress_every_s=null", "trainer=cpu",
        "trainer.enable_progress_bar=false",
    )  # fmt: skip
    checkpoint = objects.train_run(cfg) / "checkpoints" / "last.ckpt"
    fc = objects.forecaster(checkpoint)
    assert fc.fps == 25.0

    eval_cfg = case["compose"]("eval", f"ckpt_path={checkpoint}")
    dm, module = objects.evaluation_objects(eval_cfg)
    index = first_window(dm, action)
    w = dm.eval_windows[index]
    raw = archive_rows(case["archives"], dataset, w.sequence)  # 50 Hz
    at_25 = raw[2 * w.start : 2 * (w.start + OBSERVED) : 2]
    at_50 = raw[2 * w.start - 1 : 2 * (w.start + OBSERVED) - 1]  # ends on the last observed
    predicted = fc.predict(at_25, action=action)
    np.testing.assert_array_equal(fc.predict(at_50, action=action, fps=50), predicted)
    stream = fc.stream(action=action, fps=50)
    answers = [stream.push(row) for row in raw[2 * w.start : 2 * (w.start + OBSERVED) - 1]]
    np.testing.assert_allclose(answers[-1], predicted, atol=1e-5)

    # What src.eval predicts for the same window.
    item = dm.val_dataloader().dataset[index]
    with torch.no_grad():
        normalised = module.eval()(item["observed"][None], 25, action=item["action"][None])[0]
    evaluated = module.normalizer.unnormalize(normalised).numpy()
    np.testing.assert_allclose(evaluated, predicted, atol=1e-5)
