"""Metrics: rotation conversions, the Euler-angle error of the papers, forward kinematics, MPJPE."""

from src.metrics.euler_error import (
    HORIZONS_MS,
    EulerAngleError,
    euler_error_per_frame,
    expmap_frames_to_euler,
    horizon_frame_indices,
    selected_dims,
)
from src.metrics.kinematics import Skeleton, forward_kinematics, moving_joints, yz_swap
from src.metrics.mpjpe import MPJPE, mpjpe_per_frame
from src.metrics.rotations import (
    MetricInputError,
    euler_to_rotmat,
    expmap_to_euler,
    expmap_to_rotmat,
    rotmat_to_euler,
    rotmat_to_expmap,
)

__all__ = [
    "HORIZONS_MS",
    "MPJPE",
    "EulerAngleError",
    "MetricInputError",
    "Skeleton",
    "euler_error_per_frame",
    "euler_to_rotmat",
    "expmap_frames_to_euler",
    "expmap_to_euler",
    "expmap_to_rotmat",
    "forward_kinematics",
    "horizon_frame_indices",
    "moving_joints",
    "mpjpe_per_frame",
    "rotmat_to_euler",
    "rotmat_to_expmap",
    "selected_dims",
    "yz_swap",
]
