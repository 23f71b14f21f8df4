"""The Euler-angle error of protocol §4 on hand-built windows with known answers, and on S5."""

import math
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from src.metrics.euler_error import (
    HORIZONS_MS,
    EulerAngleError,
    euler_error_per_frame,
    expmap_frames_to_euler,
    horizon_frame_indices,
    selected_dims,
)
from src.metrics.rotations import MetricInputError, expmap_to_euler

F = 99
T = 25
# Rodrigues as in the reference divides by (theta + eps_float32), so a rotation by a about x
# comes out as Euler -a only to ~1e-7 (protocol §4.2); hand-computed errors are checked to 1e-6.
TOL = {"atol": 1e-6, "rtol": 0}


def row(value: float, steps: int = T) -> torch.Tensor:
    """Expected per-frame errors (1, steps): `value` everywhere."""
    return torch.full((1, steps), value, dtype=torch.float64)


def frames(batch: int = 1, steps: int = T) -> torch.Tensor:
    return torch.zeros(batch, steps, F, dtype=torch.float64)


def joint_col(joint: int, axis: int = 0) -> int:
    """Column of exp-map component `axis` of H3.6M joint `joint` (joint 0 = root at cols 3-5)."""
    return 3 + 3 * joint + axis


# --- conversion of whole frames ------------------------------------------------------------


def test_expmap_frames_to_euler_zeroes_global_and_converts_triples():
    g = torch.Generator().manual_seed(0)
    x = torch.randn(2, 4, F, generator=g, dtype=torch.float64)
    e = expmap_frames_to_euler(x)
    assert e.shape == x.shape
    assert (e[..., :6] == 0).all()
    for j in (1, 7, 31):
        c = joint_col(j)
        torch.testing.assert_close(e[..., c : c + 3], expmap_to_euler(x[..., c : c + 3]))


def test_expmap_frames_to_euler_rejects_wrong_width():
    with pytest.raises(MetricInputError, match="columns"):
        expmap_frames_to_euler(torch.zeros(2, 98))


# --- the per-frame error on windows with a known answer --------------------------------------


def moving_gt(batch: int = 1) -> torch.Tensor:
    """GT where joint 2 rotates about x by a_t = 0.05 t (so its Euler E1 = -a_t varies)."""
    gt = frames(batch)
    gt[:, :, joint_col(2)] = 0.05 * torch.arange(T, dtype=torch.float64)
    return gt


def test_single_joint_offset_gives_exactly_that_error():
    gt = moving_gt()
    pred = gt.clone()
    delta = 0.01 * (torch.arange(T, dtype=torch.float64) + 1)
    pred[:, :, joint_col(2)] += delta  # a rotation about x by a further delta_t
    err = euler_error_per_frame(pred, gt)
    assert err.shape == (1, T) and err.dtype == torch.float64
    torch.testing.assert_close(err[0], delta, **TOL)


def test_error_is_l2_over_dims_without_wrapping():
    gt = moving_gt()
    gt[:, :, joint_col(5)] = 0.02 * torch.arange(T, dtype=torch.float64)
    pred = gt.clone()
    pred[:, :, joint_col(2)] += 0.3
    pred[:, :, joint_col(5)] += 0.4
    torch.testing.assert_close(euler_error_per_frame(pred, gt), row(0.5), **TOL)
    # A difference of 2 pi - 2 in E1 is not wrapped to 2 (the reference does not wrap).
    gt2 = moving_gt()
    gt2[:, :, joint_col(2)] += math.pi - 0.9  # E1 = -(a_t + pi - 0.9), stays in (-pi, pi)
    pred2 = moving_gt()
    pred2[:, :, joint_col(2)] -= math.pi - 0.9 - 0.2  # E1 = -(a_t - pi + 1.1)
    err = euler_error_per_frame(pred2[:, :8], gt2[:, :8])
    torch.testing.assert_close(err, row(2 * math.pi - 2.0, 8), **TOL)


def test_constant_gt_dims_are_dropped():
    gt = moving_gt()
    gt[:, :, joint_col(9, 2)] = 0.3  # joint 9 constant rotation about z: std 0, dropped
    pred = gt.clone()
    pred[:, :, joint_col(9, 2)] = 0.5  # wrong, but on a dropped dim
    torch.testing.assert_close(euler_error_per_frame(pred, gt), row(0.0))
    keep = selected_dims(expmap_frames_to_euler(gt))
    assert keep[0].nonzero().flatten().tolist() == [joint_col(2)]


def test_dim_rule_uses_population_std():
    # Two future frames whose E1 differs by 1.6e-4: population std 0.8e-4 (< 1e-4, dropped);
    # the sample std (1.13e-4) would keep it. numpy's default, as in the reference, is population.
    gt = frames(steps=2)
    gt[:, :, joint_col(3)] = torch.tensor([0.5, 0.5 + 1.6e-4], dtype=torch.float64)
    pred = gt.clone()
    pred[:, :, joint_col(3)] += 0.1
    torch.testing.assert_close(euler_error_per_frame(pred, gt), row(0.0, 2))
    gt[:, 1, joint_col(3)] = 0.5 + 2.4e-4  # population std 1.2e-4: kept
    torch.testing.assert_close(euler_error_per_frame(pred, gt)[0, 0], torch.tensor(0.1).double())


def test_global_columns_never_count():
    gt = moving_gt()
    gt[:, :, :6] = torch.randn(T, 6, dtype=torch.float64)  # moving root translation/rotation
    pred = gt.clone()
    pred[:, :, :6] += 1.0
    torch.testing.assert_close(euler_error_per_frame(pred, gt), row(0.0))


def test_constant_prediction_is_not_given_zero_error():
    # The old rule (dims where the *prediction* varies, protocol §8) gave this zero error.
    gt = moving_gt()
    pred = gt[:, :1].expand_as(gt).clone()  # zero-velocity: repeat the first frame
    err = euler_error_per_frame(pred, gt)
    torch.testing.assert_close(err[0], 0.05 * torch.arange(T, dtype=torch.float64), **TOL)


def test_window_rule_uses_observed_frames():
    gt = frames()
    gt[:, :, joint_col(4)] = 0.7  # constant over the future
    observed = frames(steps=50)
    observed[:, :, joint_col(4)] = torch.linspace(0, 0.7, 50, dtype=torch.float64)
    pred = gt.clone()
    pred[:, :, joint_col(4)] += 0.1
    future = euler_error_per_frame(pred, gt, "future")
    window = euler_error_per_frame(pred, gt, "window", gt_observed_full=observed)
    torch.testing.assert_close(future, row(0.0))
    torch.testing.assert_close(window, row(0.1), **TOL)


def test_bad_arguments_raise():
    gt = moving_gt()
    with pytest.raises(MetricInputError, match="gt_observed_full"):
        euler_error_per_frame(gt, gt, "window")
    with pytest.raises(MetricInputError, match="dim_rule"):
        euler_error_per_frame(gt, gt, "prediction")
    with pytest.raises(MetricInputError, match="both be"):
        euler_error_per_frame(gt, gt[:, :3])
    with pytest.raises(MetricInputError, match="2 future frames"):
        euler_error_per_frame(gt[:, :1], gt[:, :1])
    with pytest.raises(MetricInputError, match="gt_observed_full"):
        euler_error_per_frame(gt, gt, "window", gt_observed_full=frames(batch=2, steps=50))


def test_float32_input_matches_float64():
    g = torch.Generator().manual_seed(3)
    gt = torch.randn(3, T, F, generator=g, dtype=torch.float64) * 0.5
    pred = gt + 0.1 * torch.randn(3, T, F, generator=g, dtype=torch.float64)
    e64 = euler_error_per_frame(pred, gt)
    e32 = euler_error_per_frame(pred.float(), gt.float())
    assert e32.dtype == torch.float64
    torch.testing.assert_close(e32, e64, atol=1e-5, rtol=0)


# --- horizons --------------------------------------------------------------------------------


def test_horizon_indices_of_protocol():
    assert HORIZONS_MS == (80, 160, 320, 400, 560, 1000)
    assert horizon_frame_indices() == {80: 1, 160: 3, 320: 7, 400: 9, 560: 13, 1000: 24}
    assert horizon_frame_indices(40, 10) == {80: 1, 160: 3, 320: 7, 400: 9}
    assert horizon_frame_indices(40, 24) == {80: 1, 160: 3, 320: 7, 400: 9, 560: 13}
    with pytest.raises(MetricInputError, match="frame_ms=40"):
        horizon_frame_indices(1000 / 30, 25)


# --- the torchmetrics Metric -----------------------------------------------------------------


def random_batch(batch: int, seed: int):
    g = torch.Generator().manual_seed(seed)
    gt = torch.randn(batch, T, F, generator=g, dtype=torch.float64) * 0.4
    pred = gt + 0.2 * torch.randn(batch, T, F, generator=g, dtype=torch.float64)
    action = torch.randint(0, 3, (batch,), generator=g)
    return pred, gt, action


def test_metric_mean_per_action_and_nan_for_missing_actions():
    pred, gt, _ = random_batch(5, seed=1)
    action = torch.tensor([0, 2, 0, 2, 2])
    metric = EulerAngleError(num_actions=4, num_frames=T)
    metric.update(pred, gt, action)
    out = metric.compute()
    per_window = euler_error_per_frame(pred, gt)
    assert out.shape == (4, T) and out.dtype == torch.float64
    torch.testing.assert_close(out[0], per_window[[0, 2]].mean(0))
    torch.testing.assert_close(out[2], per_window[[1, 3, 4]].mean(0))
    assert torch.isnan(out[1]).all() and torch.isnan(out[3]).all()
    assert metric.count.tolist() == [2, 0, 3, 0]


def test_metric_two_updates_equal_one_concatenated_update():
    a, b = random_batch(4, seed=2), random_batch(6, seed=3)
    split = EulerAngleError(num_actions=3, num_frames=T)
    split.update(*a)
    split.update(*b)
    whole = EulerAngleError(num_actions=3, num_frames=T)
    whole.update(*(torch.cat(pair) for pair in zip(a, b, strict=True)))
    torch.testing.assert_close(split.compute(), whole.compute(), equal_nan=True)
    assert split.count.tolist() == whole.count.tolist()


def test_metric_window_rule_and_reset():
    gt = frames(batch=2)
    gt[:, :, joint_col(4)] = 0.7
    observed = frames(batch=2, steps=50)
    observed[:, :, joint_col(4)] = torch.linspace(0, 0.7, 50, dtype=torch.float64)
    pred = gt + 0.0
    pred[:, :, joint_col(4)] += 0.1
    metric = EulerAngleError(num_actions=1, num_frames=T, dim_rule="window")
    metric.update(pred, gt, torch.zeros(2, dtype=torch.long), gt_observed_full=observed)
    torch.testing.assert_close(metric.compute(), row(0.1), **TOL)
    metric.reset()
    with warnings.catch_warnings():  # torchmetrics warns about compute() before update()
        warnings.simplefilter("ignore", UserWarning)
        assert torch.isnan(metric.compute()).all()


def test_metric_rejects_bad_actions_and_lengths():
    pred, gt, _ = random_batch(2, seed=4)
    metric = EulerAngleError(num_actions=3, num_frames=T)
    with pytest.raises(MetricInputError, match=r"\[0, 3\)"):
        metric.update(pred, gt, torch.tensor([0, 3]))
    with pytest.raises(MetricInputError, match="integer"):
        metric.update(pred, gt, torch.tensor([0.0, 1.0]))
    with pytest.raises(MetricInputError, match="num_frames"):
        metric.update(pred[:, :10], gt[:, :10], torch.tensor([0, 1]))
    with pytest.raises(MetricInputError, match="dim_rule"):
        EulerAngleError(3, T, dim_rule="pred")


# --- real data: the zero-velocity baseline of protocol §7.1 ----------------------------------

# Protocol §7.1, verified on the data; the 80-400 ms values are Martinez et al. Table 1.
ZERO_VELOCITY = {
    "walking": (0.39, 0.68, 0.99, 1.15, 1.35, 1.32),
    "eating": (0.27, 0.48, 0.73, 0.86, 1.04, 1.38),
    "smoking": (0.26, 0.48, 0.97, 0.95, 1.02, 1.69),
    "greeting": (0.54, 0.89, 1.30, 1.49, 1.79, 1.80),
}
WALKING_STARTS = [1087, 955, 1145, 332, 660, 304, 201, 54]  # protocol §3.1


def srnn_windows(seqs: dict[int, np.ndarray], length: int) -> tuple[list[int], np.ndarray]:
    """The 8 SRNN test windows (protocol §3.1), re-derived here independently of src.data."""
    rng = np.random.RandomState(1234567890)
    starts = [int(rng.randint(16, len(seqs[i % 2 + 1]) - 150)) for i in range(8)]
    windows = np.stack([seqs[i % 2 + 1][s : s + length] for i, s in enumerate(starts)])
    return starts, windows


@pytest.fixture(scope="module")
def s5_windows(archives: Path) -> dict[str, tuple[list[int], torch.Tensor]]:
    """S5 windows of 4 actions, read once per module straight from the archive (8 small files)."""
    archive = archives / "h3.6m.zip"
    if not archive.is_file():
        pytest.skip(f"{archive} does not exist")
    out = {}
    with zipfile.ZipFile(archive) as z:
        for action in ZERO_VELOCITY:
            seqs = {}
            for sub in (1, 2):
                with z.open(f"h3.6m/dataset/S5/{action}_{sub}.txt") as f:
                    seqs[sub] = np.loadtxt(f, delimiter=",")[::2]  # 25 fps (protocol §1.3)
            starts, windows = srnn_windows(seqs, 50 + T)
            out[action] = (starts, torch.from_numpy(windows))
    return out


@pytest.mark.realdata
def test_zero_velocity_reproduces_published_numbers(s5_windows):
    actions = list(ZERO_VELOCITY)
    assert s5_windows["walking"][0] == WALKING_STARTS
    metric = EulerAngleError(num_actions=len(actions), num_frames=T)
    for i, action in enumerate(actions):
        window = s5_windows[action][1]
        gt = window[:, 50:]
        pred = window[:, 49:50].expand_as(gt)  # repeat the last observed frame
        metric.update(pred, gt, torch.full((8,), i))
    result = metric.compute()
    ks = list(horizon_frame_indices().values())
    for i, action in enumerate(actions):
        ours = result[i, ks].tolist()
        np.testing.assert_allclose(ours, ZERO_VELOCITY[action], atol=0.005 + 1e-9, err_msg=action)


@pytest.mark.realdata
def test_both_dim_rules_keep_48_dims_on_s5(s5_windows):
    # Protocol §4.1 step 4: 48 Euler dims on H3.6M, with either rule.
    for action, (_, window) in s5_windows.items():
        observed = expmap_frames_to_euler(window[:, :50])
        future = expmap_frames_to_euler(window[:, 50:])
        assert selected_dims(future).sum(-1).tolist() == [48] * 8, action
        assert selected_dims(future, "window", observed).sum(-1).tolist() == [48] * 8, action
