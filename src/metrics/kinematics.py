"""Forward kinematics: exp-map pose vectors -> 3D joint positions, for MPJPE and display. The
kinematic trees (skeletons/*.json) are those of the two papers' reference code, from the shared
data folder (its README, section Skeletons), with its conventions: row vectors (a point v is
rotated as v @ R, R the Rodrigues matrix of protocol §4.2); a joint's position is its offset
rotated by the parent's accumulated rotation plus the parent's position, its accumulated rotation
its own @ the parent's; y is up (the reference swaps y and z only for display, yz_swap)."""

import json
from dataclasses import dataclass
from importlib import resources

import torch
from torch import Tensor

from src.metrics.rotations import MetricInputError, expmap_to_rotmat

SKELETONS = ("h36m", "cmu")


@dataclass(frozen=True, eq=False)
class Skeleton:
    """A kinematic tree, joints in topological order (parents[j] < j), joint 0 the root; offsets
    (J, 3) float64 in the skeleton's units (mm on H3.6M; CMU's the reference's, scaled by 70);
    expmap_columns (J, 3) each joint's exp-map columns (joint 0: the global rotation, 3-5)."""

    name: str
    parents: tuple[int, ...]
    offsets: Tensor
    expmap_columns: Tensor

    def __post_init__(self) -> None:
        J = len(self.parents)
        if self.offsets.shape != (J, 3) or self.expmap_columns.shape != (J, 3):
            raise MetricInputError(
                f"skeleton {self.name!r}: {J} parents but offsets {tuple(self.offsets.shape)} and "
                f"expmap_columns {tuple(self.expmap_columns.shape)}; each needs shape ({J}, 3)"
            )
        if J == 0 or self.parents[0] != -1:
            raise MetricInputError(f"skeleton {self.name!r}: joint 0 must be the root (parent -1)")
        if any(not 0 <= p < j for j, p in enumerate(self.parents) if j > 0):
            raise MetricInputError(
                f"skeleton {self.name!r}: every joint's parent must come before it (parents[j] < j)"
            )

    @property
    def num_joints(self) -> int:
        return len(self.parents)

    @property
    def num_columns(self) -> int:
        """F, the length of the pose vectors this skeleton reads (99 for H3.6M, 117 for CMU)."""
        return int(self.expmap_columns.max()) + 1

    @classmethod
    def load(cls, name: str) -> "Skeleton":
        """The packaged skeleton "h36m" (32 joints) or "cmu" (38 joints)."""
        if name not in SKELETONS:
            raise MetricInputError(f"unknown skeleton {name!r}; choose one of {SKELETONS}")
        text = resources.files("src.metrics").joinpath(f"skeletons/{name}.json").read_text()
        raw = json.loads(text)
        return cls(
            name=name,
            parents=tuple(int(p) for p in raw["parents"]),
            offsets=torch.tensor(raw["offsets"], dtype=torch.float64),
            expmap_columns=torch.tensor(raw["expmap_columns"], dtype=torch.long),
        )


def forward_kinematics(x_full: Tensor, skeleton: Skeleton, zero_global: bool = True) -> Tensor:
    """3D joint positions (..., J, 3) of unnormalised exp-map pose vectors (..., F).

    zero_global=True (the metric convention, SRNN's, protocol §4.1 step 3): the root has no
    translation and rotation, poses are compared in the body frame. With False, columns 0-2
    translate and 3-5 rotate the root (H3.6M stores them as per-frame increments, §1.1: integrate
    them first for a trajectory). The reference also adds its `position_columns_1based` to each
    offset: a joint's own exp-map (radians added to millimetres), the root's global rotation;
    with no geometric meaning and in no metric, it is left out."""
    if not isinstance(x_full, Tensor) or not x_full.is_floating_point():
        raise MetricInputError("x_full must be a floating torch.Tensor of unnormalised exp-maps")
    F = skeleton.num_columns
    if x_full.dim() < 1 or x_full.shape[-1] != F:
        raise MetricInputError(
            f"skeleton {skeleton.name!r} reads {F} columns, got x_full of shape "
            f"{tuple(x_full.shape)}; pass full unnormalised frames (normalizer.unnormalize)"
        )
    cols = skeleton.expmap_columns.to(x_full.device)
    rot = expmap_to_rotmat(x_full[..., cols])  # (..., J, 3, 3)
    offsets = skeleton.offsets.to(device=x_full.device, dtype=x_full.dtype)

    lead = x_full.shape[:-1]
    if zero_global:
        root_rot = torch.eye(3, dtype=x_full.dtype, device=x_full.device).expand(*lead, 3, 3)
        root_pos = offsets[0].expand(*lead, 3)
    else:
        root_rot = rot[..., 0, :, :]
        root_pos = offsets[0] + x_full[..., :3]
    positions, rotations = [root_pos], [root_rot]
    for j in range(1, skeleton.num_joints):
        p = skeleton.parents[j]
        positions.append(offsets[j] @ rotations[p] + positions[p])
        rotations.append(rot[..., j, :, :] @ rotations[p])
    return torch.stack(positions, -2)


def moving_joints(skeleton: Skeleton, used_columns: Tensor) -> Tensor:
    """Indices of the joints whose position the metric can see move, sorted: those (a) with a
    non-zero offset (else they duplicate the parent), (b) with an ancestor other than the root
    that has a used exp-map column (the metric zeroes the root's rotation, and ignored columns
    come back as the constant training mean, protocol §2.2) and (c) not at the same parent and
    offset as an earlier joint (e.g. the H3.6M shoulders' bases). The usual 22 on H3.6M (§2.1)."""
    used = torch.as_tensor(used_columns)
    if used.dtype != torch.bool or used.shape != (skeleton.num_columns,):
        raise MetricInputError(
            f"used_columns must be a bool tensor ({skeleton.num_columns},), got "
            f"{used.dtype} {tuple(used.shape)}"
        )
    joint_used = used[skeleton.expmap_columns].any(-1).tolist()
    offsets = skeleton.offsets.tolist()
    keep = []
    for j in range(skeleton.num_joints):
        if not any(offsets[j]):
            continue
        ancestor, moves = skeleton.parents[j], False
        while ancestor > 0:  # stop at the root (index 0)
            moves = moves or joint_used[ancestor]
            ancestor = skeleton.parents[ancestor]
        twin = any(
            skeleton.parents[i] == skeleton.parents[j] and offsets[i] == offsets[j]
            for i in range(j)
        )
        if moves and not twin:
            keep.append(j)
    return torch.tensor(keep, dtype=torch.long)


def yz_swap(positions: Tensor) -> Tensor:
    """Swap the y and z coordinates (..., 3), as the reference does before plotting."""
    if positions.shape[-1] != 3:
        raise MetricInputError(f"positions must be (..., 3), got {tuple(positions.shape)}")
    return positions[..., [0, 2, 1]]
