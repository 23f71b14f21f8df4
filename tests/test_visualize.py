"""Visualisation: the visualize command, stick figures that stand upright with the right bones,
frame strips, error-versus-horizon plots and the TensorBoard frame-strip callback."""

import json

import matplotlib
import numpy as np
import pytest
import torch
from PIL import Image

from src.config import ConfigError
from src.metrics.kinematics import Skeleton, forward_kinematics, yz_swap
from src.plot_errors import plot_errors
from src.plots import (
    PoseRow,
    animate,
    error_vs_horizon,
    frame_strip,
    skeleton_bones,
    strip_frames,
    window_rows,
)
from src.results import build_for_evaluation, result_table
from src.visualize import select_window
from tests.conftest import compose_config, refused, run_module

matplotlib.use("Agg")

# Head and feet in the two kinematic trees (skeletons/*.json): the top of the neck chain and
# the two toe sites.
HEAD_FEET = {"h36m": (15, (5, 10)), "cmu": (19, (6, 12))}


def _green_pixels(frame: Image.Image) -> int:
    rgb = np.asarray(frame.convert("RGB")).astype(int)
    rgb = rgb[rgb.shape[0] // 3 :]  # below the titles, which are coloured as their rows
    return int(((rgb[..., 1] > rgb[..., 0] + 50) & (rgb[..., 1] > rgb[..., 2] + 30)).sum())


def test_visualize_command_writes_gif_and_strip(tmp_path, synthetic_data_dir):
    proc = run_module(
        "src.visualize",
        "model=zero_velocity",
        "data=synthetic",
        "action=walking",
        "observed_shown=5",
        data_dir=synthetic_data_dir,
        log_dir=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    (gif,) = tmp_path.glob("visualize/runs/zero_velocity_synthetic_walking/*/walking_w0.gif")
    (png,) = gif.parent.glob("walking_w0_strip.png")
    strip = Image.open(png)
    assert strip.size[0] > 800
    anim = Image.open(gif)
    assert anim.n_frames == 5 + 25  # observed_shown + future_len
    # Observed frames are grey, the ground-truth future green: none at the start, some at the end.
    anim.seek(0)
    first = _green_pixels(anim)
    anim.seek(anim.n_frames - 1)
    assert first == 0 and _green_pixels(anim) > 50


@pytest.mark.parametrize(
    ("override", "kind"),
    [
        ("window=abc", "Integer"),  # Hydra's words: the schema of conf/visualize.yaml
        ("window=1.5", "Integer"),
        ("observed_shown=abc", "Integer"),
        ("observed_shown=0", ">= 1"),
        ("strip_step=0", ">= 1"),
        ("strip_step=-2", ">= 1"),
        ("baseline=nope", "bool"),
    ],
)
def test_visualize_settings_of_the_wrong_type_or_range_are_refused(override, kind, tmp_path):
    """window=abc, observed_shown=abc and strip_step=0 used to end in a traceback; window=1.5
    drew window 1 into a file named w1.5, baseline=nope drew the baseline."""
    from hydra.errors import ConfigCompositionException

    from src.cli import hydra_error
    from src.visualize import visualize

    try:
        cfg = compose_config("visualize", ["model=zero_velocity", "data=h36m", override], tmp_path)
        with pytest.raises(ConfigError) as err:
            visualize(cfg)
        message = str(err.value)
    except ConfigCompositionException as hydra_err:
        message = hydra_error(hydra_err, "visualize")
    refused(message, override.split("=")[0], override.split("=")[1], kind)


@pytest.fixture(scope="module")
def synthetic_baseline(tmp_path_factory, synthetic_data_dir):
    cfg = compose_config(
        "visualize",
        ["model=zero_velocity", "data=synthetic"],
        tmp_path_factory.mktemp("viz"),
        synthetic_data_dir,
    )
    return build_for_evaluation(cfg)


def test_window_rows_put_observed_frames_before_future(synthetic_baseline):
    dm, module = synthetic_baseline
    index = select_window(dm, "eating", 1)
    assert dm.eval_windows[index].action == "eating"
    rows, n_obs, what = window_rows(dm, module, index, observed_shown=10)
    # The model is zero-velocity itself, so no extra baseline row.
    assert [r.label for r in rows] == ["prediction (zero_velocity)", "ground truth"]
    assert n_obs == 10 and all(r.positions.shape == (10 + 25, 32, 3) for r in rows)
    pred, truth = rows[0].positions, rows[1].positions
    np.testing.assert_allclose(pred[:n_obs], truth[:n_obs])  # same observed frames
    np.testing.assert_allclose(pred[n_obs:], np.repeat(truth[n_obs - 1 : n_obs], 25, 0))
    assert not np.allclose(truth[n_obs:], truth[n_obs - 1])  # the synthetic motion moves
    assert f"eating, window 1 ({dm.eval_windows[index].sequence}, start " in what
    assert f"start {dm.eval_windows[index].start}" in what


def test_select_window_names_the_valid_range(synthetic_baseline):
    dm, _ = synthetic_baseline
    n = sum(w.action == "walking" for w in dm.eval_windows)
    with pytest.raises(ConfigError, match=rf"walking has {n} evaluation windows"):
        select_window(dm, "walking", n)
    with pytest.raises(ConfigError, match="not in this data's actions"):
        select_window(dm, "dancing", 0)


@pytest.mark.parametrize("name", ["h36m", "cmu"])
def test_rest_pose_stands_upright_after_yz_swap(name):
    skeleton = Skeleton.load(name)
    zeros = torch.zeros(1, skeleton.num_columns, dtype=torch.float64)
    xyz = yz_swap(forward_kinematics(zeros, skeleton))[0]
    head, feet = HEAD_FEET[name]
    # Matplotlib's 3D z axis is vertical: head above the hips (root) above both feet, about a
    # body height apart (both skeletons are in millimetre-like units).
    z = xyz[:, 2]
    assert z[head] > z[0] > z[list(feet)].max()
    assert 1500 < z[head] - z[list(feet)].max() < 2000


@pytest.mark.parametrize("name", ["h36m", "cmu"])
def test_bones_follow_parents_and_skip_zero_length(name):
    skeleton = Skeleton.load(name)
    bones = skeleton_bones(skeleton)
    zero = [j for j in range(1, skeleton.num_joints) if not skeleton.offsets[j].any()]
    # 31 (H3.6M) / 37 (CMU) parent links, minus the 4 / 10 zero-offset joints.
    assert len(bones) == 27
    assert len(bones) == skeleton.num_joints - 1 - len(zero)
    assert all(skeleton.parents[c] == p for p, c in bones)
    assert not {c for _, c in bones} & set(zero)


def test_strip_frames_end_at_last_observed_and_last_future_frame():
    assert strip_frames(50, 75, step=3, n_before=3) == [43, 46, 49, *range(50, 75, 3)]
    assert strip_frames(10, 35, step=5, n_before=2) == [4, 9, 14, 19, 24, 29, 34]
    with pytest.raises(ValueError, match="n_observed"):
        strip_frames(0, 10)


def test_frame_strip_draws_each_bone_of_each_pose():
    skeleton = Skeleton.load("h36m")
    frames = torch.zeros(8, skeleton.num_columns, dtype=torch.float64)
    frames[:, 6] = torch.linspace(0, 1, 8)  # bend the right hip more and more
    xyz = yz_swap(forward_kinematics(frames, skeleton)).numpy()
    rows = [PoseRow("a", xyz), PoseRow("b", xyz, "green")]
    fig = frame_strip(rows, skeleton, n_observed=4, step=2, n_before=2)
    cols = strip_frames(4, 8, 2, 2)
    assert len(fig.axes) == 2 * len(cols)
    bones = skeleton_bones(skeleton)
    last = fig.axes[len(cols) - 1]  # row "a", frame 7
    drawn = np.concatenate([np.stack(line.get_data_3d(), 1) for line in last.lines])
    drawn = drawn[~np.isnan(drawn).any(1)].reshape(-1, 2, 3)  # one (parent, child) per bone
    expected = {tuple(np.round(xyz[7, [p, c]], 6).ravel()) for p, c in bones}
    assert len(drawn) == len(bones)
    assert {tuple(np.round(d, 6).ravel()) for d in drawn} == expected
    assert [ax.get_title() for ax in fig.axes[: len(cols)]] == [
        "-80 ms",
        "0 ms",
        "+80 ms",
        "+160 ms",
    ]
    with pytest.raises(ValueError, match="positions must be"):
        frame_strip([PoseRow("bad", xyz[:, :, :2])], skeleton, 4)


def test_animate_has_one_frame_per_motion_frame():
    skeleton = Skeleton.load("cmu")
    xyz = yz_swap(forward_kinematics(torch.zeros(6, 117, dtype=torch.float64), skeleton)).numpy()
    anim = animate([PoseRow("x", xyz)], skeleton, n_observed=3)
    assert len(list(anim.new_frame_seq())) == 6
    html = anim.to_jshtml(fps=25)
    assert "<img" in html or "data:image/png" in html


def _results_json(path, values, published=None):
    tables = []
    for metric, unit in (("euler", "rad"), ("mpjpe", "mm")):
        tables.append(
            result_table(
                f"{metric} test",
                metric,
                unit,
                ["walking", "eating"],
                [80, 160],
                {"walking": values},
                {"eating": "missing test file(s)"},
                published,
                "paper X" if published else None,
            )
        )
    path.write_text(
        json.dumps({"provenance": {"model": path.stem, "dataset": "h36m"}, "tables": tables})
    )
    return path


def test_plot_errors_draws_one_line_per_results_file(tmp_path):
    a = _results_json(tmp_path / "a.json", {80: 0.2, 160: 0.4})
    b = _results_json(tmp_path / "b.json", {80: 0.3, 160: 0.5}, {"walking": {80: 0.25, 160: 0.45}})
    out = plot_errors([a, b], tmp_path / "plots" / "e.png", action="walking", published=True)
    assert Image.open(out).size == (600, 400)
    fig = error_vs_horizon([("a", {80: 0.2, 160: 0.4}), ("b", {"80": 0.3, "160": 0.5})])
    (ax,) = fig.axes
    assert [list(line.get_ydata()) for line in ax.lines] == [[0.2, 0.4], [0.3, 0.5]]
    assert list(ax.lines[1].get_xdata()) == [80, 160]
    with pytest.raises(ConfigError, match="eating is absent"):
        plot_errors([a], tmp_path / "x.png", action="eating")
    with pytest.raises(ConfigError, match="choose one of"):
        plot_errors([a], tmp_path / "x.png", metric="l2")
    with pytest.raises(ConfigError, match="not found"):
        plot_errors([tmp_path / "none.json"], tmp_path / "x.png")


def _image_tags(folder):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(folder), size_guidance={"images": 0})
    acc.Reload()
    return {tag: [e.step for e in acc.Images(tag)] for tag in acc.Tags()["images"]}


def test_media_callback_logs_frame_strip_to_tensorboard(train_cfg, tmp_path):
    from src.train import train

    cfg = train_cfg("model=conv_s2s", "adversarial=none", "iterations=2", "val_every=2")
    assert cfg.media_every == 1
    train(cfg)
    tags = _image_tags(tmp_path / "run" / "tensorboard")
    assert tags == {"media/walking_window0": [2]}


def test_media_callback_off_with_media_every_zero(train_cfg, tmp_path):
    from src.lit.callbacks import FrameStripLogger

    assert FrameStripLogger.from_config(train_cfg("media_every=0")) == []
    (cb,) = FrameStripLogger.from_config(train_cfg("media_every=3"))
    assert cb.every_n_validations == 3
    with pytest.raises(ValueError, match="every_n_validations"):
        FrameStripLogger(every_n_validations=0)
