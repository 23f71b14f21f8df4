"""Rotation conversions against scipy (an independent implementation) and round-trip identities."""

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from src.metrics.rotations import (
    MetricInputError,
    euler_to_rotmat,
    expmap_to_euler,
    expmap_to_rotmat,
    rotmat_to_euler,
    rotmat_to_expmap,
)

N = 2000


def random_rotations(n: int = N, seed: int = 0) -> Rotation:
    return Rotation.random(n, random_state=seed)


def away_from_gimbal(rot: Rotation, margin: float = 0.05) -> Rotation:
    """Keep rotations whose middle XYZ angle is at least `margin` rad from +-pi/2."""
    middle = rot.as_euler("XYZ")[:, 1]
    return rot[np.abs(middle) < math.pi / 2 - margin]


def test_expmap_to_rotmat_matches_scipy_rotvec():
    rotvec = random_rotations().as_rotvec()
    ours = expmap_to_rotmat(torch.from_numpy(rotvec))
    # The eps of the reference formula (k = r / (theta + eps_float32)) costs ~1e-7.
    np.testing.assert_allclose(ours.numpy(), Rotation.from_rotvec(rotvec).as_matrix(), atol=1e-6)


def test_expmap_to_rotmat_float32_and_leading_dims():
    r = torch.randn(2, 3, 4, 3, generator=torch.Generator().manual_seed(1))
    R = expmap_to_rotmat(r)
    assert R.shape == (2, 3, 4, 3, 3) and R.dtype == torch.float32
    R64 = expmap_to_rotmat(r.double())
    torch.testing.assert_close(R.double(), R64, atol=1e-5, rtol=0)


def test_expmap_to_rotmat_known_values():
    # 90 degrees about z maps x to y (active rotation, R @ v).
    R = expmap_to_rotmat(torch.tensor([0.0, 0.0, math.pi / 2], dtype=torch.float64))
    x, y = torch.eye(3, dtype=torch.float64)[:2]
    torch.testing.assert_close(R @ x, y, atol=1e-6, rtol=0)
    torch.testing.assert_close(expmap_to_rotmat(torch.zeros(3)), torch.eye(3))


def test_rotmat_to_euler_matches_scipy_xyz_negated():
    rot = away_from_gimbal(random_rotations())
    ours = rotmat_to_euler(torch.from_numpy(rot.as_matrix()))
    np.testing.assert_allclose(ours.numpy(), -rot.as_euler("XYZ"), atol=1e-10)


def test_expmap_to_euler_matches_scipy():
    # The ~1e-7 eps error of Rodrigues grows like 1/cos(E2) near gimbal lock; stay 0.2 away.
    rot = away_from_gimbal(random_rotations(seed=3), margin=0.2)
    ours = expmap_to_euler(torch.from_numpy(rot.as_rotvec()))
    np.testing.assert_allclose(ours.numpy(), -rot.as_euler("XYZ"), atol=1e-6)


def test_euler_known_value_single_axis():
    # Exp-map 0.5 about x is Rx(0.5) = Rx(-E1): E1 = -0.5 (protocol §4.2).
    e = expmap_to_euler(torch.tensor([0.5, 0.0, 0.0], dtype=torch.float64))
    torch.testing.assert_close(e, torch.tensor([-0.5, 0.0, 0.0], dtype=torch.float64))


def test_euler_to_rotmat_is_rx_ry_rz_of_negated_angles():
    e = np.array([[0.3, -0.7, 1.9], [-2.5, 1.2, -0.4]])
    expected = Rotation.from_euler("XYZ", -e).as_matrix()
    np.testing.assert_allclose(euler_to_rotmat(torch.from_numpy(e)).numpy(), expected, atol=1e-12)


def test_euler_round_trip_within_canonical_ranges():
    g = torch.Generator().manual_seed(2)
    e = torch.rand(N, 3, generator=g, dtype=torch.float64) * 2 - 1
    e = e * torch.tensor([math.pi - 1e-6, math.pi / 2 - 1e-3, math.pi - 1e-6], dtype=torch.float64)
    torch.testing.assert_close(rotmat_to_euler(euler_to_rotmat(e)), e, atol=1e-9, rtol=0)


def test_rotmat_euler_rotmat_round_trip():
    R = torch.from_numpy(random_rotations(seed=4).as_matrix())
    torch.testing.assert_close(euler_to_rotmat(rotmat_to_euler(R)), R, atol=1e-9, rtol=0)


def test_expmap_round_trip_same_rotation_and_same_vector():
    rotvec = random_rotations(seed=5).as_rotvec()  # scipy's rotvecs have angle in [0, pi]
    r = torch.from_numpy(rotvec)
    back = rotmat_to_expmap(expmap_to_rotmat(r))
    # Tolerances: the reference's eps in Rodrigues leaves R ~1e-7 off orthogonal.
    torch.testing.assert_close(expmap_to_rotmat(back), expmap_to_rotmat(r), atol=1e-6, rtol=0)
    torch.testing.assert_close(back, r, atol=1e-6, rtol=0)


def test_rotmat_to_expmap_on_exact_rotations():
    rot = random_rotations(seed=6)
    back = rotmat_to_expmap(torch.from_numpy(rot.as_matrix()))
    np.testing.assert_allclose(back.numpy(), rot.as_rotvec(), atol=1e-10)


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-7, 1e-3, 1.0, math.pi - 1e-3, math.pi - 1e-9])
def test_rotmat_to_expmap_near_zero_and_pi(angle):
    axis = np.array([0.36, -0.48, 0.8])  # unit
    rotvec = axis * angle
    R = torch.from_numpy(Rotation.from_rotvec(rotvec).as_matrix())
    back = rotmat_to_expmap(R).numpy()
    np.testing.assert_allclose(back, rotvec, atol=1e-9)


def test_rotmat_to_expmap_at_exactly_pi():
    axis = np.array([0.36, -0.48, 0.8])
    R = torch.from_numpy(Rotation.from_rotvec(axis * math.pi).as_matrix())
    back = rotmat_to_expmap(R).numpy()
    assert np.linalg.norm(back) == pytest.approx(math.pi, abs=1e-9)
    # r and -r are the same rotation at pi; either is right.
    assert min(np.abs(back - axis * math.pi).max(), np.abs(back + axis * math.pi).max()) < 1e-8


def test_gimbal_branch_reproduces_reference_formulas():
    # R[0,2] exactly +1: E3 = 0, E2 = -pi/2, E1 = atan2(R[0,1], R[0,2]) = atan2(0, 1) = 0.
    ry = torch.tensor([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]], dtype=torch.float64)
    torch.testing.assert_close(
        rotmat_to_euler(ry), torch.tensor([0.0, -math.pi / 2, 0.0], dtype=torch.float64)
    )
    # R[0,2] exactly -1: E2 = pi/2 and E1 = atan2(0, -1) = pi (the reference's formula; it does
    # not recover the rotation, which is why nobody should hit this branch on purpose).
    torch.testing.assert_close(
        rotmat_to_euler(ry.T), torch.tensor([math.pi, math.pi / 2, 0.0], dtype=torch.float64)
    )


def test_gimbal_branch_formula_on_inexact_matrix():
    # Rounded matrices can have R[0,2] exactly 1 with a small R[0,1]: E1 = atan2(R[0,1], R[0,2]),
    # E2 = -pi/2, E3 = 0, exactly as the reference computes it.
    R = torch.tensor([[0.0, 1e-3, 1.0], [0.2, 1.0, 0.0], [-1.0, 0.3, 0.0]], dtype=torch.float64)
    expected = torch.tensor([math.atan2(1e-3, 1.0), -math.pi / 2, 0.0], dtype=torch.float64)
    torch.testing.assert_close(rotmat_to_euler(R), expected)


def test_gradients_are_finite_at_identity_and_gimbal():
    r = torch.zeros(2, 3, dtype=torch.float64, requires_grad=True)
    expmap_to_euler(r).sum().backward()
    assert torch.isfinite(r.grad).all()

    R = torch.eye(3, dtype=torch.float64).repeat(2, 1, 1).requires_grad_()
    rotmat_to_expmap(R).sum().backward()
    assert torch.isfinite(R.grad).all()

    gimbal = torch.tensor([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]], dtype=torch.float64)
    gimbal.requires_grad_()
    rotmat_to_euler(gimbal).sum().backward()
    assert torch.isfinite(gimbal.grad).all()


def test_gradcheck_on_smooth_inputs():
    g = torch.Generator().manual_seed(7)
    r = (torch.rand(4, 3, generator=g, dtype=torch.float64) - 0.5).requires_grad_()
    assert torch.autograd.gradcheck(expmap_to_euler, (r,))
    R = torch.from_numpy(away_from_gimbal(random_rotations(8, seed=9)).as_matrix())
    assert torch.autograd.gradcheck(rotmat_to_expmap, (R.requires_grad_(),))
    e = (torch.rand(4, 3, generator=g, dtype=torch.float64) - 0.5).requires_grad_()
    assert torch.autograd.gradcheck(euler_to_rotmat, (e,))


@pytest.mark.parametrize(
    "fn, bad",
    [
        (expmap_to_rotmat, torch.zeros(5, 4)),
        (expmap_to_rotmat, torch.zeros(5, 3, dtype=torch.long)),
        (rotmat_to_euler, torch.zeros(5, 3)),
        (rotmat_to_expmap, torch.zeros(3, 4)),
        (euler_to_rotmat, np.zeros(3)),
    ],
)
def test_bad_input_raises_clear_error(fn, bad):
    with pytest.raises(MetricInputError, match="must"):
        fn(bad)
