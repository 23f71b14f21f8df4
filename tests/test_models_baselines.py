"""Zero-velocity and running-average baselines (Martinez et al. 2017 §4, protocol §7.1)."""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from src.metrics.rotations import expmap_to_euler
from src.models import RunningAverage, ZeroVelocity


class FakeNormalizer:
    """Same methods as src.data.normalization.Normalizer: z = ((x - mean) / std)[used]."""

    def __init__(self, mean, std, used):
        self.mean, self.std, self.used = mean, std, used

    def normalize(self, x):
        return ((x - self.mean.to(x.dtype)) / self.std.to(x.dtype))[..., self.used]

    def unnormalize(self, z):
        x = self.mean.to(z.dtype).expand(*z.shape[:-1], -1).clone()
        x[..., self.used] = z * self.std.to(z.dtype)[self.used] + self.mean.to(z.dtype)[self.used]
        return x


def make_normalizer(F=9):
    # Root translation (3) + 2 exp-map joints (6); column 1 unused (constant in the "data").
    mean = torch.linspace(-0.1, 0.1, F, dtype=torch.float64)
    std = torch.linspace(0.5, 1.5, F, dtype=torch.float64)
    used = torch.ones(F, dtype=torch.bool)
    used[1] = False
    return FakeNormalizer(mean, std, used)


def test_zero_velocity_repeats_frame_49():
    observed = torch.randn(3, 50, 54)
    model = ZeroVelocity(pose_dim=54, num_actions=15)
    out = model(observed, 25, action=torch.tensor([0, 1, 2]), future=torch.randn(3, 25, 54))
    assert out.shape == (3, 25, 54)
    for t in range(25):
        torch.testing.assert_close(out[:, t], observed[:, 49], rtol=0, atol=0)
    assert ZeroVelocity.trainable is False and not list(model.parameters())


def test_running_average_k2_is_the_euler_mean():
    norm = make_normalizer()
    a, b = 0.8, 1.1
    # Frame 48: root (1, 2, 3), joint 1 rotated by a about x, joint 2 by 0.3 about y.
    # Frame 49: root (3, 2, 5), joint 1 rotated by b about z, joint 2 by 0.5 about y.
    raw = torch.zeros(1, 50, 9, dtype=torch.float64)
    raw[0, 48] = torch.tensor([1.0, 2.0, 3.0, a, 0, 0, 0, 0.3, 0], dtype=torch.float64)
    raw[0, 49] = torch.tensor([3.0, 2.0, 5.0, 0, 0, b, 0, 0.5, 0], dtype=torch.float64)
    raw[0, :, 1] = norm.mean[1]  # the unused column holds the training mean, as in real data
    observed = norm.normalize(raw).float()

    model = RunningAverage(pose_dim=8, num_actions=15, k=2, normalizer=norm)
    out = model(observed, 4)
    assert out.shape == (1, 4, 8) and out.dtype == torch.float32
    pred = norm.unnormalize(out.double())[0]
    for t in range(4):
        torch.testing.assert_close(pred[t], pred[0], rtol=0, atol=0)

    # Hand-computed: SRNN Euler of Rx(a) is (-a, 0, 0), of Rz(b) is (0, 0, -b) (R = Rx(-E1)
    # Ry(-E2) Rz(-E3)); their mean (-a/2, 0, -b/2) is the rotation Rx(a/2) Rz(b/2), whose
    # exp-map we take from scipy (composition r1 * r2 = matrix R1 @ R2).
    joint1 = (Rotation.from_rotvec([a / 2, 0, 0]) * Rotation.from_rotvec([0, 0, b / 2])).as_rotvec()
    expected = np.concatenate([[2.0, norm.mean[1].item(), 4.0], joint1, [0, 0.4, 0]])
    torch.testing.assert_close(pred[0], torch.from_numpy(expected), atol=1e-5, rtol=0)
    # ...which is not the plain exp-map mean (a/2, 0, b/2): the Euler step matters.
    assert (pred[0, 3:6] - torch.tensor([a / 2, 0, b / 2], dtype=torch.float64)).abs().max() > 1e-2
    euler = expmap_to_euler(pred[0, 3:6])
    torch.testing.assert_close(
        euler, torch.tensor([-a / 2, 0, -b / 2], dtype=torch.float64), atol=1e-5, rtol=0
    )


def test_running_average_k1_is_zero_velocity():
    norm = make_normalizer()
    raw = torch.rand(2, 50, 9, dtype=torch.float64) * 2 - 1
    raw[..., 1] = norm.mean[1]
    observed = norm.normalize(raw).float()
    zero = ZeroVelocity(pose_dim=8, num_actions=15)(observed, 10)
    avg1 = RunningAverage(pose_dim=8, num_actions=15, k=1, normalizer=norm)
    torch.testing.assert_close(avg1(observed, 10), zero, rtol=0, atol=0)
    # The general Euler path agrees for k = 1 in Euler space (up to float rounding).
    mean = avg1.euler_mean(observed[:, -1:])
    last = norm.unnormalize(observed[:, -1].double())
    torch.testing.assert_close(mean[:, :3], last[:, :3])
    to_euler = lambda x: expmap_to_euler(x[:, 3:].reshape(2, -1, 3))  # noqa: E731
    torch.testing.assert_close(to_euler(mean), to_euler(last), atol=1e-6, rtol=0)


def test_running_average_k4_uses_only_the_last_four_frames():
    norm = make_normalizer()
    raw = torch.rand(2, 50, 9, dtype=torch.float64) - 0.5
    raw[..., 1] = norm.mean[1]
    observed = norm.normalize(raw).float()
    model = RunningAverage(pose_dim=8, num_actions=15, k=4, normalizer=norm)
    out = model(observed, 3)
    changed = observed.clone()
    changed[:, :46] += 1.0  # frames before 46 must not matter
    torch.testing.assert_close(model(changed, 3), out, rtol=0, atol=0)
    changed[:, 46] += 0.1
    assert not torch.allclose(model(changed, 3), out)
    assert RunningAverage.trainable is False and not list(model.parameters())


def test_running_average_bad_arguments():
    norm = make_normalizer()
    with pytest.raises(ValueError, match="k=0"):
        RunningAverage(pose_dim=8, num_actions=15, k=0, normalizer=norm)
    with pytest.raises(TypeError, match="normalize"):
        RunningAverage(pose_dim=8, num_actions=15, k=2, normalizer=object())
    model = RunningAverage(pose_dim=8, num_actions=15, k=2, normalizer=norm)
    with pytest.raises(ValueError, match=r"observed must be \(B, T, 8\)"):
        model(torch.zeros(1, 50, 9), 3)
    with pytest.raises(ValueError, match="k=2 exceeds"):
        model(torch.zeros(1, 1, 8), 3)
