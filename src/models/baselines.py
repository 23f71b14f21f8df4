"""Parameter-free baselines of Martinez et al. 2017 §4 (protocol §7.1).

Zero-velocity repeats the last observed frame; the running average of k frames predicts, for
every future frame, the mean of the last k observed frames (49-k+1 .. 49), in **Euler-angle**
space as [M] src/baselines.py and its published numbers: normalised -> exp-map -> Euler ->
mean -> exp-map -> normalised. Dropping the ignored columns in the last step loses nothing: on
H3.6M they are exactly 0 in the data (constant joints, the y, z parts of the 1-DOF joints), and
the Euler mean of rotations about x alone is again one about x.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from src.metrics.rotations import (
    euler_to_rotmat,
    expmap_to_rotmat,
    rotmat_to_euler,
    rotmat_to_expmap,
)
from src.models.conv_s2s import check_forward_inputs


class ZeroVelocity(nn.Module):
    """Predict the last observed frame (frame 49) for every future frame."""

    trainable = False

    def __init__(self, pose_dim: int, num_actions: int):
        super().__init__()
        self.pose_dim, self.num_actions = pose_dim, num_actions

    def forward(self, observed: Tensor, future_len: int, action=None, future=None, eta=1.0):
        """(B, T_obs, D) -> (B, future_len, D); action, future and eta are ignored."""
        B = check_forward_inputs(observed, None, self.pose_dim, future_len, future, eta)
        return observed[:, -1:].expand(B, future_len, self.pose_dim).clone()


class RunningAverage(nn.Module):
    """Predict the Euler-space mean of the last k observed frames (2 and 4 in Martinez Table 1)
    for every future frame: columns 0-2 (root translation) as they are, every following exp-map
    triple as SRNN Euler angles (protocol §4.2). k = 1 is zero-velocity, frame 49 unchanged (no
    float round trip). normalizer: the datamodule's Normalizer, or any object with normalize
    (..., F) -> (..., D) and unnormalize (..., D) -> (..., F)."""

    trainable = False

    def __init__(self, pose_dim: int, num_actions: int, k: int, normalizer: nn.Module):
        super().__init__()
        if k < 1:
            raise ValueError(f"k={k} must be >= 1 (number of observed frames to average)")
        if not all(callable(getattr(normalizer, f, None)) for f in ("normalize", "unnormalize")):
            raise TypeError(
                "normalizer must provide normalize() and unnormalize(); pass the datamodule's "
                f"Normalizer, got {type(normalizer).__name__}"
            )
        if getattr(normalizer, "pose_dim", pose_dim) != pose_dim:
            raise ValueError(
                f"pose_dim={pose_dim} but the normalizer has {normalizer.pose_dim} used columns"
            )
        self.pose_dim, self.num_actions, self.k = pose_dim, num_actions, k
        self.normalizer = normalizer

    def forward(self, observed: Tensor, future_len: int, action=None, future=None, eta=1.0):
        """(B, T_obs, D) -> (B, future_len, D); action, future and eta are ignored."""
        B = check_forward_inputs(observed, None, self.pose_dim, future_len, future, eta)
        if observed.shape[1] < self.k:
            raise ValueError(f"k={self.k} exceeds the {observed.shape[1]} observed frames")
        if self.k == 1:
            mean = observed[:, -1]
        else:
            mean = self.normalizer.normalize(self.euler_mean(observed[:, -self.k :]))
            mean = mean.to(observed.dtype)
        return mean.unsqueeze(1).expand(B, future_len, self.pose_dim).clone()

    def euler_mean(self, frames: Tensor) -> Tensor:
        """Normalised frames (B, k, D) -> raw exp-map mean pose (B, F), Euler-space mean."""
        raw = self.normalizer.unnormalize(frames.double())  # float64 as [M]'s numpy code
        euler = rotmat_to_euler(expmap_to_rotmat(raw[..., 3:].unflatten(-1, (-1, 3))))
        rot = rotmat_to_expmap(euler_to_rotmat(euler.mean(dim=1)))  # (B, J, 3)
        return torch.cat([raw[..., :3].mean(dim=1), rot.flatten(1)], dim=1)
