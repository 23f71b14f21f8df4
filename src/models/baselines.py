"""Parameter-free baselines of Martinez et al. 2017 §4 (protocol §7.1).

Zero-velocity repeats the last observed frame; the running average of k frames predicts,
for every future frame, the mean of the last k observed frames (49-k+1 .. 49). [M] takes
that mean in **Euler-angle** space (each frame is converted to Euler angles before
averaging, [M] src/baselines.py), which is what the published running-average numbers
measure, so we do the same: normalised -> exp-map -> Euler -> mean -> exp-map -> normalised.

The last step drops the ignored columns again. That loses nothing: on H3.6M every ignored
column is exactly 0 in the data (whole constant joints, and the y, z parts of the 1-DOF
joints), and the Euler mean of rotations about x alone is again a rotation about x, so the
error of our prediction equals the error of [M]'s Euler-space mean.
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

    def forward(
        self,
        observed: Tensor,
        future_len: int,
        action: Tensor | None = None,
        future: Tensor | None = None,
        eta: float = 1.0,
    ) -> Tensor:
        """(B, T_obs, D) -> (B, future_len, D); action, future and eta are ignored."""
        B = check_forward_inputs(observed, None, self.pose_dim, future_len, future, eta)
        return observed[:, -1:].expand(B, future_len, self.pose_dim).clone()


class RunningAverage(nn.Module):
    """Predict the Euler-space mean of the last k observed frames for every future frame.

    Columns 0-2 (root translation) are averaged as they are; every following triple is an
    exp-map rotation, averaged as Euler angles (SRNN convention, protocol §4.2). k = 1 is the
    zero-velocity baseline and returns frame 49 unchanged (no float round trip).

    Args:
        pose_dim: D, used dimensions.
        num_actions: unused, for the common constructor contract.
        k: number of observed frames averaged (2 and 4 in Martinez Table 1).
        normalizer: the datamodule's Normalizer, or any object with normalize (..., F) ->
            (..., D) and unnormalize (..., D) -> (..., F); F - 3 must be a multiple of 3.
    """

    trainable = False

    def __init__(self, pose_dim: int, num_actions: int, k: int, normalizer: nn.Module):
        super().__init__()
        if k < 1:
            raise ValueError(f"k={k} must be >= 1 (number of observed frames to average)")
        for name in ("normalize", "unnormalize"):
            if not callable(getattr(normalizer, name, None)):
                raise TypeError(
                    f"normalizer must provide {name}(); pass the datamodule's Normalizer, "
                    f"got {type(normalizer).__name__}"
                )
        if getattr(normalizer, "pose_dim", pose_dim) != pose_dim:
            raise ValueError(
                f"pose_dim={pose_dim} but the normalizer has {normalizer.pose_dim} used columns"
            )
        self.pose_dim, self.num_actions, self.k = pose_dim, num_actions, k
        self.normalizer = normalizer

    def forward(
        self,
        observed: Tensor,
        future_len: int,
        action: Tensor | None = None,
        future: Tensor | None = None,
        eta: float = 1.0,
    ) -> Tensor:
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
        B, k, F = raw.shape
        if F < 3 or (F - 3) % 3:
            raise ValueError(
                f"unnormalised frames have {F} columns; expected 3 root-translation columns "
                "followed by exp-map triples (99 on H3.6M, 117 on CMU)"
            )
        root = raw[..., :3].mean(dim=1)
        euler = rotmat_to_euler(expmap_to_rotmat(raw[..., 3:].reshape(B, k, -1, 3)))
        rot = rotmat_to_expmap(euler_to_rotmat(euler.mean(dim=1)))  # (B, J, 3)
        return torch.cat([root, rot.reshape(B, -1)], dim=1)
