"""MotionForecaster: checkpoint -> raw-frame predictions, streaming, export.

One tiny training run (2 iterations, synthetic H3.6M-format data) writes the checkpoint the
tests load; the forecaster must rebuild the network without reading any data file."""

from __future__ import annotations

import inspect
import warnings

import numpy as np
import pytest
import torch

from src.data.normalization import Normalizer
from src.data.synthetic import write_synthetic_h36m
from src.inference import COMPILED_SHAPES, InferenceInputError, MotionForecaster
from src.lit.checkpoints import CheckpointError, read_checkpoint
from src.models.conv_s2s import ConvSeq2Seq
from src.models.gru_s2s import GRUSeq2Seq
from src.prepare import compose_config
from src.train import train

F = 99  # H3.6M raw columns


@pytest.fixture(scope="module")
def ckpt_path(tmp_path_factory):
    root = tmp_path_factory.mktemp("inference")
    write_synthetic_h36m(root / "data" / "synthetic")
    cfg = compose_config(
        "train",
        [
            "data=synthetic",
            "trainer=cpu",
            "iterations=2",
            "val_every=2",
            "adversarial=none",
            "model.net.nf=4",
            "model.net.d_z=32",
            "+model.net.d_dec=32",
        ],
        root / "run",
        root / "data",
    )
    train(cfg)
    paths = sorted((root / "run").rglob("last.ckpt"))
    assert paths, "the tiny training run wrote no last.ckpt"
    return paths[0]


@pytest.fixture(scope="module")
def forecaster(ckpt_path):
    return MotionForecaster.from_checkpoint(ckpt_path)


@pytest.fixture(scope="module")
def frames():
    rng = np.random.default_rng(0)
    return (0.3 * rng.standard_normal((4, 60, F))).astype(np.float32)


def reference_prediction(ckpt_path, x: np.ndarray, future_len: int) -> np.ndarray:
    """By hand from the checkpoint: the network of the fixture's config with the saved weights,
    normalise (§2.1), predict, unnormalise."""
    state = read_checkpoint(ckpt_path)["state_dict"]
    norm = Normalizer(state["normalizer.mean"], state["normalizer.std"], state["normalizer.used"])
    net = ConvSeq2Seq(norm.pose_dim, 3, nf=4, d_z=32, d_dec=32, padding="same").eval()
    net.load_state_dict({k.removeprefix("net."): v for k, v in state.items() if k[:4] == "net."})
    with torch.no_grad():
        pred = net(norm.normalize(torch.as_tensor(x)), future_len)
        return norm.unnormalize(pred).numpy()


def test_rebuilds_weights_and_normaliser_from_the_checkpoint_alone(ckpt_path, forecaster):
    state = read_checkpoint(ckpt_path)["state_dict"]
    torch.testing.assert_close(forecaster.normalizer.mean, state["normalizer.mean"])
    w = forecaster.net.decoder[0].weight
    torch.testing.assert_close(w, state["net.decoder.0.weight"])
    assert forecaster.net.short_encoder.shapes[0][0] == 16  # nf=4 from the run's config


def test_predict_batch_and_single_match_the_manual_pipeline(ckpt_path, forecaster, frames):
    x = frames[:, :50]
    out = forecaster.predict(x)
    assert out.shape == (4, 25, F)
    np.testing.assert_allclose(out, reference_prediction(ckpt_path, x, 25), rtol=1e-4, atol=1e-5)
    one = forecaster.predict(x[2], future_len=10)
    assert one.shape == (10, F)
    np.testing.assert_allclose(one, out[2, :10], rtol=1e-4, atol=1e-5)
    # Columns the model ignores come back as the training mean (protocol §2.2).
    unused = ~forecaster.normalizer.used.numpy()
    np.testing.assert_allclose(
        out[..., unused],
        np.broadcast_to(forecaster.normalizer.mean.numpy()[unused], out[..., unused].shape),
        atol=1e-6,
    )


def test_bad_inputs_raise_clear_errors(forecaster, frames):
    with pytest.raises(InferenceInputError, match="F=99"):
        forecaster.predict(frames[0, :50, :54])
    with pytest.raises(InferenceInputError, match=r"\(50, 99\) or \(B, 50, 99\)"):
        forecaster.predict(frames[0, :49])
    bad = frames[0, :50].copy()
    bad[7, 3] = np.nan
    with pytest.raises(InferenceInputError, match=r"NaN.*\[7, 3\]"):
        forecaster.predict(bad)
    with pytest.raises(InferenceInputError, match="unknown action"):
        forecaster.predict(frames[0, :50], action="flying")
    with pytest.raises(CheckpointError, match="not found"):
        MotionForecaster.from_checkpoint("/nonexistent/last.ckpt")


def test_frames_in_degrees_are_refused_naming_the_unit_and_the_fix(forecaster, frames):
    """Degrees were forecast as if radians, without a word. Exp-map angles of real motion stay
    within pi (at most 3.1416 in every frame of the real archives); the root position (columns
    0-2) is no angle, and columns the model ignores (48-50 here) are not read."""
    degrees = np.rad2deg(frames[:, :50])
    for call in (
        lambda: forecaster.predict(degrees),
        lambda: forecaster.stream().push(degrees[0, 0]),
    ):
        with pytest.raises(InferenceInputError) as info:
            call()
        assert "degrees" in str(info.value) and "np.deg2rad" in str(info.value)
    x = frames[0, :50].copy()
    x[:, :3] = 5000.0
    x[:, 3:6] = [np.pi, 0.0, 0.0]
    x[:, 48:51] = 180.0
    assert not forecaster.normalizer.used[48:51].any()
    assert forecaster.predict(x).shape == (25, F)


def test_a_checkpoint_whose_config_this_version_cannot_build_is_refused(ckpt_path, tmp_path):
    """A network setting this version no longer has (4b904c1 took model.net.incremental): one
    CheckpointError naming the file, not Hydra's instantiation traceback."""
    ckpt = torch.load(ckpt_path, map_location="cpu", weights_only=True)
    del ckpt["hyper_parameters"]  # as before the module saved its own: built from "motion"
    ckpt["motion"]["config"]["model"]["net"]["incremental"] = False
    old = tmp_path / "old.ckpt"
    torch.save(ckpt, old)
    with pytest.raises(CheckpointError, match=f"cannot rebuild the model of {old}.*incremental"):
        MotionForecaster.from_checkpoint(old)


def test_a_device_that_cannot_be_used_is_refused_by_name(ckpt_path, monkeypatch):
    with pytest.raises(InferenceInputError, match="device='gpu' is not a torch device"):
        MotionForecaster.from_checkpoint(ckpt_path, device="gpu")
    # As on a machine without CUDA (torch would assert at the first copy to the device).
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(InferenceInputError, match="device='cuda', but this torch .* no CUDA"):
        MotionForecaster.from_checkpoint(ckpt_path, device="cuda")


def test_stream_matches_predict_on_each_window(forecaster, frames):
    stream = forecaster.stream()
    seq = frames[0]
    for t in range(53):
        out = stream.push(seq[t])
        if t < 49:
            assert out is None
        else:  # window = frames t-49..t
            expected = forecaster.predict(seq[t - 49 : t + 1])
            np.testing.assert_allclose(out, expected, rtol=1e-4, atol=1e-5)
    with pytest.raises(InferenceInputError, match=r"one frame of shape \(99,\)"):
        stream.push(seq[:2])


def test_exports_reproduce_the_eager_model(forecaster, frames, tmp_path):
    norm = forecaster.normalizer
    x = norm.normalize(torch.as_tensor(frames[:2, :50]))
    action = torch.zeros(2, dtype=torch.long)
    with torch.no_grad():
        eager = forecaster.net(x, 25)
    scripted = torch.jit.load(str(forecaster.export_torchscript(tmp_path / "m.pt")))
    torch.testing.assert_close(scripted(x, action), eager, rtol=1e-4, atol=1e-5)
    # onnx's reference evaluator: slow but exact, and needs no onnxruntime
    reference = pytest.importorskip("onnx.reference")
    path = forecaster.export_onnx(tmp_path / "m.onnx")
    sess = reference.ReferenceEvaluator(str(path))
    (out,) = sess.run(None, {"observed": x.numpy(), "action": action.numpy()})
    np.testing.assert_allclose(out, eager.numpy(), rtol=1e-4, atol=1e-5)


def test_one_hot_model_requires_the_action():
    from src.data.normalization import Normalizer
    from src.inference import InferenceInputError, MotionForecaster
    from src.models.gru_s2s import GRUSeq2Seq

    normalizer = Normalizer.from_sequences([np.random.default_rng(0).normal(size=(100, 99))])
    net = GRUSeq2Seq(pose_dim=normalizer.pose_dim, num_actions=2, hidden=8, one_hot=True)
    forecaster = MotionForecaster(net, normalizer, ["walking", "eating"], 50, "cpu")
    frames = np.zeros((50, 99), dtype=np.float32)
    with pytest.raises(InferenceInputError, match="pass action="):
        forecaster.predict(frames)
    assert forecaster.predict(frames, action="eating").shape == (25, 99)


def test_compile_is_off_by_default(ckpt_path):
    """On every device ("auto" would compile on CUDA): compiling is asked for, never implied."""
    assert not MotionForecaster.from_checkpoint(ckpt_path).compiled
    for make in (MotionForecaster, MotionForecaster.from_checkpoint):
        assert inspect.signature(make).parameters["compile"].default is False
    assert MotionForecaster.from_checkpoint(ckpt_path, compile=True).compiled
    with pytest.raises(ValueError, match="compile=.yes. must be true, false or auto"):
        MotionForecaster.from_checkpoint(ckpt_path, compile="yes")


def test_a_compiled_forecaster_predicts_ten_shapes(ckpt_path, frames, dynamo_only):
    """Each new (batch size, future_len) is a new graph of the network's forward, and torch
    refused the 9th (recompile_limit 8, an error under fullgraph). Past COMPILED_SHAPES
    shapes new ones run eagerly, with one warning; every shape predicts what eager does."""
    eager = MotionForecaster.from_checkpoint(ckpt_path)
    compiled = MotionForecaster.from_checkpoint(ckpt_path, compile=True)
    shapes = [(b, t) for t in (1, 2, 3) for b in (1, 2, 3)] + [(4, 1)]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for b, t in shapes:
            x = frames[:b, :50]
            out = compiled.predict(x, future_len=t)
            np.testing.assert_allclose(out, eager.predict(x, future_len=t), rtol=1e-4, atol=1e-5)
        assert compiled.stream(future_len=2).push(frames[0, 0]) is None  # a stream, too
    (warned,) = [w for w in caught if "run eagerly" in str(w.message)]
    assert f"compiled {COMPILED_SHAPES} (batch size, future_len) shapes" in str(warned.message)
    assert warned.filename == __file__  # names the caller's line
    assert len(compiled._shapes) == COMPILED_SHAPES


def test_forecasters_of_several_structures_compile_in_one_process(dynamo_only):
    """Networks of one class share torch's limit of graphs: three forecasters of 4 shapes each
    are 12 graphs of GRUSeq2Seq.forward. Past the limit torch predicts eagerly."""
    normalizer = Normalizer.from_sequences([np.random.default_rng(0).normal(size=(100, F))])
    frames = np.zeros((4, 50, F), dtype=np.float32)
    for hidden in (4, 5, 6):
        net = GRUSeq2Seq(pose_dim=normalizer.pose_dim, num_actions=1, hidden=hidden, one_hot=False)
        compiled = MotionForecaster(net, normalizer, ["walking"], compile=True)
        eager = MotionForecaster(net, normalizer, ["walking"])
        for b in range(1, COMPILED_SHAPES + 1):
            out = compiled.predict(frames[:b], future_len=2)
            np.testing.assert_allclose(out, eager.predict(frames[:b], future_len=2), atol=1e-6)


DEVICES = [
    "cpu",
    pytest.param(
        "cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
    ),
]


@pytest.mark.slow
@pytest.mark.parametrize("device", DEVICES)
def test_compiled_forecaster_predicts_what_the_eager_one_does(
    ckpt_path, frames, device, monkeypatch
):
    """Compiled (on CUDA: one CUDA graph per shape) against eager, batch and single, and the
    stream. Each shape compiles once."""
    if device == "cuda":  # exact float32 matmuls on both sides
        monkeypatch.setattr(torch.backends.cuda.matmul, "allow_tf32", False)
        monkeypatch.setattr(torch.backends.cudnn, "allow_tf32", False)
    eager = MotionForecaster.from_checkpoint(ckpt_path, device=device, compile=False)
    compiled = MotionForecaster.from_checkpoint(ckpt_path, device=device, compile=True)
    assert compiled._run is not compiled.net and eager._run is eager.net
    x = frames[:, :50]
    for _ in range(2):  # the second call replays what the first captured
        np.testing.assert_allclose(compiled.predict(x), eager.predict(x), rtol=1e-4, atol=1e-5)
    stream = compiled.stream()
    for t in range(52):
        out = stream.push(frames[1, t])
        if t >= 49:
            expected = eager.predict(frames[1, t - 49 : t + 1])
            np.testing.assert_allclose(out, expected, rtol=1e-4, atol=1e-5)


def test_reversed_and_flipped_views_are_accepted(forecaster, frames):
    """np.flip and [::-1] give negative strides, which torch.as_tensor refuses."""
    x = np.ascontiguousarray(frames[0, :50][::-1])
    expected = forecaster.predict(x)
    np.testing.assert_array_equal(forecaster.predict(frames[0, :50][::-1]), expected)
    np.testing.assert_array_equal(forecaster.predict(np.flip(frames[0, :50], 0)), expected)


@pytest.mark.parametrize("future_len", [0, -3, 2.5, "25"])
def test_bad_future_len_is_refused_by_predict_and_stream(forecaster, frames, future_len):
    with pytest.raises(InferenceInputError, match="future_len must be an integer >= 1"):
        forecaster.predict(frames[0, :50], future_len=future_len)
    with pytest.raises(InferenceInputError, match="future_len must be an integer >= 1"):
        forecaster.stream(future_len=future_len)


def test_future_len_accepts_numpy_integers(forecaster, frames):
    assert forecaster.predict(frames[0, :50], future_len=np.int64(3)).shape == (3, F)


@pytest.mark.parametrize("dtype", [torch.bfloat16, torch.float16, torch.float64])
def test_torch_frames_of_any_float_dtype_are_accepted(forecaster, frames, dtype):
    """bfloat16 (mixed-precision pipelines) has no numpy dtype; .numpy() of it raises."""
    x = torch.from_numpy(frames[0, :50]).to(dtype)
    expected = forecaster.predict(x.float().numpy())
    np.testing.assert_array_equal(forecaster.predict(x), expected)


def test_ragged_or_non_numeric_frames_raise_clear_errors(forecaster, frames):
    ragged = [list(f) for f in frames[0, :50]]
    ragged[7] = ragged[7][:98]  # one frame lost a column
    with pytest.raises(InferenceInputError, match="numeric array"):
        forecaster.predict(ragged)
    with pytest.raises(InferenceInputError, match="numeric array"):
        forecaster.predict("walking")
    with pytest.raises(InferenceInputError, match="numeric array"):
        forecaster.stream().push({"frame": 1})


def test_the_frame_rate_is_stated_and_other_rates_are_subsampled_or_refused(forecaster, frames):
    """Issue #26 row 14: 50 consecutive raw rows (50 Hz on H3.6M) used to be forecast as if
    they were 2 s at 25 fps, without a word."""
    assert forecaster.fps == 25.0  # every other row of the files (protocol §1.3)
    raw = np.concatenate([frames[:, :50], frames[:, 10:60]], axis=1)  # (4, 100, F) at 50 fps
    np.testing.assert_allclose(
        forecaster.predict(raw, fps=50), forecaster.predict(raw[:, 1::2]), rtol=1e-5, atol=1e-6
    )
    np.testing.assert_allclose(
        forecaster.predict(raw[0, 50:], fps=25.0), forecaster.predict(raw[0, 50:]), atol=0
    )
    with pytest.raises(InferenceInputError, match=r"\(100, 99\) or \(B, 100, 99\) at 50 fps"):
        forecaster.predict(raw[0, :50], fps=50)  # 1 s of 50 fps frames
    with pytest.raises(InferenceInputError, match="fps=30: this model forecasts from frames at 25"):
        forecaster.predict(raw[0], fps=30)
    for bad in (0, -25, True, "50"):
        with pytest.raises(InferenceInputError, match="fps must be a positive number"):
            forecaster.predict(raw[0, :50], fps=bad)
    with pytest.raises(InferenceInputError, match="fps=60"):
        forecaster.stream(fps=60)


def test_a_stream_at_twice_the_rate_uses_every_other_frame(forecaster, frames):
    seq = np.concatenate([frames[0], frames[1]])  # 120 frames at 50 fps
    stream = forecaster.stream(fps=50)
    answers = [stream.push(frame) for frame in seq[:103]]
    assert all(a is None for a in answers[:98]) and answers[99] is None
    kept = seq[0:103:2]  # frames 0, 2, 4, ...: the first push is used
    np.testing.assert_allclose(answers[98], forecaster.predict(kept[:50]), rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(answers[102], forecaster.predict(kept[2:52]), rtol=1e-4, atol=1e-5)
