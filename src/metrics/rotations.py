"""Rotation conversions of the metrics: exp-map <-> rotation matrix <-> SRNN Euler angles, on torch
tensors of any leading shape, in the input's dtype and device, differentiable where the map is
smooth. Not scipy's Rotation: the published numbers depend on the exact convention of SRNN's
`RotMat2Euler.m` (protocol §4.2), down to its branch for R[0,2] exactly +-1, which no library
reproduces, and the metrics need batched tensors on any device. The tests use scipy as an oracle:
`Rotation.from_rotvec(r).as_matrix()` equals `expmap_to_rotmat(r)` to ~1e-7 (the reference's eps,
below), `-Rotation.from_matrix(R).as_euler("XYZ")` equals `rotmat_to_euler(R)` away from gimbal
lock to ~1e-10 in float64."""

import math

import torch
from torch import Tensor

# The reference divides by (theta + eps) with eps = float32 machine epsilon, whatever the
# dtype of the data (protocol §4.2); keep that constant so float64 results match too.
EPS_FLOAT32 = float(torch.finfo(torch.float32).eps)


class MetricInputError(ValueError):
    """A metric or conversion got a tensor of the wrong shape, dtype or value range."""


def _check_last_dims(x: Tensor, shape: tuple[int, ...], name: str) -> None:
    if not isinstance(x, Tensor):
        raise MetricInputError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
    if tuple(x.shape[-len(shape) :]) != shape or x.dim() < len(shape):
        raise MetricInputError(
            f"{name} must have shape (..., {', '.join(map(str, shape))}), got {tuple(x.shape)}"
        )
    if not x.is_floating_point():
        raise MetricInputError(f"{name} must be a floating tensor, got {x.dtype}; call .float()")


def _skew(k: Tensor) -> Tensor:
    """Cross-product matrix [k]x of (..., 3) vectors, shape (..., 3, 3)."""
    zero = torch.zeros_like(k[..., 0])
    kx, ky, kz = k.unbind(-1)
    return torch.stack((zero, -kz, ky, kz, zero, -kx, -ky, kx, zero), -1).unflatten(-1, (3, 3))


def expmap_to_rotmat(r: Tensor) -> Tensor:
    """Exp-map (axis * angle, (..., 3)) to rotation matrix (..., 3, 3) by Rodrigues' formula,
    exactly as the reference (protocol §4.2): theta = |r|, k = r / (theta + eps_float32),
    R = I + sin(theta) [k]x + (1 - cos(theta)) [k]x^2, the active rotation (R @ v rotates v)."""
    _check_last_dims(r, (3,), "expmap")
    theta = torch.linalg.vector_norm(r, dim=-1, keepdim=True)
    k = _skew(r / (theta + EPS_FLOAT32))
    theta = theta.unsqueeze(-1)
    eye = torch.eye(3, dtype=r.dtype, device=r.device)
    return eye + torch.sin(theta) * k + (1.0 - torch.cos(theta)) * (k @ k)


def rotmat_to_euler(R: Tensor) -> Tensor:
    """Rotation matrix (..., 3, 3) to SRNN Euler angles (E1, E2, E3), port of SRNN's RotMat2Euler
    (protocol §4.2): E2 = -asin(R[0,2]), E1 = atan2(R[1,2], R[2,2]), E3 = atan2(R[0,1], R[0,0]);
    R = Rx(-E1) Ry(-E2) Rz(-E3). The reference divides both atan2 arguments by cos(E2) >= 0,
    which cancels: left out, as it only adds rounding and blows up gradients near |R[0,2]| = 1.

    Gimbal branch, only where R[0,2] is exactly +-1 as in the reference: E3 = 0,
    d = atan2(R[0,1], R[0,2]); R[0,2] = -1 gives (E1, E2) = (d, pi/2), +1 gives (d, -pi/2). Its
    d reads R[0,1] = 0, so the rotation about the locked axis is lost; reproduced all the same,
    as the published numbers were computed with it (real data never reaches it)."""
    _check_last_dims(R, (3, 3), "rotation matrix")
    r02, r01, r00 = R[..., 0, 2], R[..., 0, 1], R[..., 0, 0]
    r12, r22 = R[..., 1, 2], R[..., 2, 2]
    gimbal = (r02 == 1.0) | (r02 == -1.0)

    # Feed harmless values to the regular branch at gimbal entries, so that torch.where does not
    # pick up NaN/inf gradients from asin'(+-1) or atan2(0, 0) of the branch it discards.
    safe_r02 = torch.where(gimbal, torch.zeros_like(r02), r02).clamp(-1.0, 1.0)
    safe_r22 = torch.where(gimbal, torch.ones_like(r22), r22)
    safe_r00 = torch.where(gimbal, torch.ones_like(r00), r00)
    e1 = torch.atan2(r12, safe_r22)
    e2 = -torch.asin(safe_r02)
    e3 = torch.atan2(r01, safe_r00)

    delta = torch.atan2(r01, r02)
    half_pi = torch.full_like(r02, math.pi / 2)
    e1 = torch.where(gimbal, delta, e1)
    e2 = torch.where(gimbal, torch.where(r02 == -1.0, half_pi, -half_pi), e2)
    e3 = torch.where(gimbal, torch.zeros_like(e3), e3)
    return torch.stack((e1, e2, e3), -1)


def expmap_to_euler(r: Tensor) -> Tensor:
    """Exp-map (..., 3) to SRNN Euler angles (..., 3): rotmat_to_euler(expmap_to_rotmat(r))."""
    return rotmat_to_euler(expmap_to_rotmat(r))


def _axis_rotation(angle: Tensor, axis: int) -> Tensor:
    """Standard active rotation about x (0), y (1) or z (2) by `angle` (...,) -> (..., 3, 3)."""
    c, s = torch.cos(angle), torch.sin(angle)
    one, zero = torch.ones_like(angle), torch.zeros_like(angle)
    if axis == 0:
        rows = (one, zero, zero, zero, c, -s, zero, s, c)
    elif axis == 1:
        rows = (c, zero, s, zero, one, zero, -s, zero, c)
    else:
        rows = (c, -s, zero, s, c, zero, zero, zero, one)
    return torch.stack(rows, -1).unflatten(-1, (3, 3))


def euler_to_rotmat(e: Tensor) -> Tensor:
    """SRNN Euler angles (..., 3) to rotation matrix R = Rx(-E1) Ry(-E2) Rz(-E3) (protocol §4.2),
    the inverse of rotmat_to_euler for E1, E3 in (-pi, pi] and E2 in (-pi/2, pi/2)."""
    _check_last_dims(e, (3,), "euler")
    rx = _axis_rotation(-e[..., 0], 0)
    ry = _axis_rotation(-e[..., 1], 1)
    rz = _axis_rotation(-e[..., 2], 2)
    return rx @ ry @ rz


def rotmat_to_expmap(R: Tensor) -> Tensor:
    """Rotation matrix (..., 3, 3) to exp-map (..., 3) with angle in [0, pi].

    Goes through a unit quaternion by Shepperd's method (take the square root of the largest of
    the four quaternion "diagonals", which is >= 1/4, and get the other components from
    off-diagonal sums/differences), so it is accurate near angle 0 and near pi where the
    textbook log map (axis from R - R^T divided by sin(theta)) loses all precision. At exactly
    pi, r and -r are the same rotation; either may be returned.
    """
    _check_last_dims(R, (3, 3), "rotation matrix")
    r00, r01, r02 = R[..., 0, 0], R[..., 0, 1], R[..., 0, 2]
    r10, r11, r12 = R[..., 1, 0], R[..., 1, 1], R[..., 1, 2]
    r20, r21, r22 = R[..., 2, 0], R[..., 2, 1], R[..., 2, 2]
    # d = 4 * (w^2, x^2, y^2, z^2); they sum to 4, so the largest is >= 1.
    p, m = 1.0 + r00, 1.0 - r00
    d = (p + r11 + r22, p - r11 - r22, m + r11 - r22, m - r11 + r22)
    # 4 * q_i * q_j for the off-diagonal pairs (w,x) (w,y) (w,z) (x,y) (x,z) (y,z).
    wx, wy, wz = r21 - r12, r02 - r20, r10 - r01
    xy, xz, yz = r01 + r10, r02 + r20, r12 + r21
    # Candidate quaternions (w, x, y, z), each scaled by 4 * (its pivot component).
    rows = ((d[0], wx, wy, wz), (wx, d[1], xy, xz), (wy, xy, d[2], yz), (wz, xz, yz, d[3]))
    cands = torch.stack([torch.stack(row, -1) for row in rows], -2)
    diag = torch.stack(d, -1)
    pivot = diag.argmax(-1, keepdim=True)
    q = torch.gather(cands, -2, pivot.unsqueeze(-1).expand(*pivot.shape[:-1], 1, 4)).squeeze(-2)
    q = q / torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    q = torch.where(q[..., :1] < 0, -q, q)  # w >= 0: angle in [0, pi]

    w, v = q[..., 0], q[..., 1:]
    s = torch.linalg.vector_norm(v, dim=-1)  # sin(theta / 2)
    small = s < 1e-4
    # theta / s = 2 atan2(s, w) / s; its series 2/w (1 - s^2 / (3 w^2)) is exact to O(s^4) for
    # small s and avoids 0/0 (and NaN gradients) at the identity.
    safe_s = torch.where(small, torch.ones_like(s), s)
    scale = torch.where(
        small,
        (2.0 / w) * (1.0 - s * s / (3.0 * w * w)),
        2.0 * torch.atan2(safe_s, w) / safe_s,
    )
    return v * scale.unsqueeze(-1)
