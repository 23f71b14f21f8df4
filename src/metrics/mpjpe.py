"""Mean per-joint position error (MPJPE) of predicted poses, per action and future frame.

Not a metric of the two papers (they report only the Euler error of protocol §4); it is the
position-space error later work reports, computed here from the same unnormalised exp-maps by
forward kinematics with the global translation and rotation zeroed, in the skeleton's units
(mm on H3.6M).
"""

import torch
from torch import Tensor

from src.metrics.euler_error import PerActionMean
from src.metrics.kinematics import Skeleton, forward_kinematics
from src.metrics.rotations import MetricInputError


def mpjpe_per_frame(
    pred_full: Tensor, gt_full: Tensor, skeleton: Skeleton, joints: Tensor
) -> Tensor:
    """Per-window, per-frame MPJPE (B, T) in float64: mean over `joints` of the 3D distance."""
    if pred_full.dim() != 3 or pred_full.shape != gt_full.shape:
        raise MetricInputError(
            f"pred_full and gt_full must both be (B, T, F); got {tuple(pred_full.shape)} and "
            f"{tuple(gt_full.shape)}"
        )
    pred = forward_kinematics(pred_full.double(), skeleton)
    gt = forward_kinematics(gt_full.double(), skeleton)
    joints = joints.to(pred.device)
    return torch.linalg.vector_norm(pred[..., joints, :] - gt[..., joints, :], dim=-1).mean(-1)


class MPJPE(PerActionMean):
    """Mean MPJPE per action and future frame, (A, T), over ``joints``, e.g.
    moving_joints(skeleton, used_columns) (22 on H3.6M); NaN for actions without windows."""

    def __init__(
        self, skeleton: Skeleton, joints: Tensor, num_actions: int, num_frames: int, **kwargs
    ):
        super().__init__(num_actions, num_frames, **kwargs)
        joints = torch.as_tensor(joints, dtype=torch.long)
        J = skeleton.num_joints
        if joints.dim() != 1 or not len(joints) or joints.min() < 0 or joints.max() >= J:
            raise MetricInputError(
                f"joints must be a non-empty 1-D tensor of joint indices in [0, {J}) for "
                f"skeleton {skeleton.name!r}, got {joints.tolist()}"
            )
        self.skeleton, self.joints = skeleton, joints

    def update(self, pred_full: Tensor, gt_full: Tensor, action: Tensor) -> None:
        self.add(mpjpe_per_frame(pred_full, gt_full, self.skeleton, self.joints), action)
