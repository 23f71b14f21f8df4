"""Forward kinematics, the moving-joint subset and MPJPE, against hand-computed geometry."""

import os
from pathlib import Path

import pytest
import torch

from src.metrics.kinematics import Skeleton, forward_kinematics, moving_joints, yz_swap
from src.metrics.mpjpe import MPJPE, mpjpe_per_frame
from src.metrics.rotations import MetricInputError

# Rodrigues with the reference's eps (protocol §4.2) is orthogonal only to ~1e-7 relative, so
# geometry is checked to 1e-6 relative (1e-4 mm on bones of a few hundred mm).

# Protocol §2.1: the 54 used H3.6M columns.
H36M_USED_RANGES = [(0, 9), (12, 15), (21, 24), (27, 30), (36, 47), (51, 57), (60, 62), (75, 81)]
H36M_USED_RANGES += [(84, 86)]
# Protocol §2.3: the 47 ignored CMU columns.
CMU_IGNORED = [6, 7, 8, 14, *range(20, 27), 32, *range(38, 42), *range(60, 66), 69, 73, 74, 78]
CMU_IGNORED += [79, 81, 82, 83, *range(87, 93), 96, 100, 101, 105, 106, 108, 109, 110]
CMU_IGNORED += [114, 115, 116]

# Hand-derived (see moving_joints): all joints except the root-only chains' first joints
# (1, 6, 11), zero offsets (0, 20, 23, 28, 31) and the shoulder bases 16 and 24, which share
# parent 12 and offset (0, 257.08, 0) with joint 13.
H36M_MOVING = [2, 3, 4, 5, 7, 8, 9, 10, 12, 13, 14, 15, 17, 18, 19, 21, 22, 25, 26, 27, 29, 30]
# CMU: zero offsets 0 1 7 13 16 20 24 27 29 33 36 out; 2 and 8 hang only below the root and
# joints 1 and 7, whose exp-map columns (6-8, 24-26) are all ignored.
CMU_MOVING = [3, 4, 5, 6, 9, 10, 11, 12, 14, 15, 17, 18, 19, 21, 22, 23, 25, 26, 28, 30, 31, 32]
CMU_MOVING += [34, 35, 37]


def h36m_used() -> torch.Tensor:
    used = torch.zeros(99, dtype=torch.bool)
    for lo, hi in H36M_USED_RANGES:
        used[lo : hi + 1] = True
    return used


@pytest.fixture(scope="module")
def h36m() -> Skeleton:
    return Skeleton.load("h36m")


def col(skeleton: Skeleton, joint: int, axis: int) -> int:
    return int(skeleton.expmap_columns[joint, axis])


def descendants(skeleton: Skeleton, joint: int) -> set[int]:
    out: set[int] = set()
    for j in range(skeleton.num_joints):
        a = skeleton.parents[j]
        while a >= 0:
            if a == joint:
                out.add(j)
            a = skeleton.parents[a]
    return out


# --- skeleton files --------------------------------------------------------------------------


def test_skeletons_load():
    h, c = Skeleton.load("h36m"), Skeleton.load("cmu")
    assert (h.num_joints, h.num_columns, c.num_joints, c.num_columns) == (32, 99, 38, 117)
    assert h.expmap_columns[0].tolist() == [3, 4, 5] and c.expmap_columns[0].tolist() == [3, 4, 5]
    assert h.offsets.dtype == torch.float64
    with pytest.raises(MetricInputError, match="h36m"):
        Skeleton.load("h3.6m")


def shared_skeleton_dir() -> Path | None:
    candidates = [Path("/work/shared/data/skeletons")]
    if os.environ.get("MOTION_ARCHIVES"):
        candidates.insert(0, Path(os.environ["MOTION_ARCHIVES"]) / "skeletons")
    return next((p for p in candidates if p.is_dir()), None)


@pytest.mark.parametrize("name", ["h36m", "cmu"])
def test_packaged_skeletons_equal_the_shared_copies(name):
    shared = shared_skeleton_dir()
    if shared is None:
        pytest.skip("no shared skeletons folder ($MOTION_ARCHIVES/skeletons) to compare with")
    packaged = Path(__file__).parents[1] / "src" / "metrics" / "skeletons" / f"{name}.json"
    assert packaged.read_bytes() == (shared / f"{name}_skeleton.json").read_bytes()


def test_skeleton_validation():
    with pytest.raises(MetricInputError, match="parents"):
        Skeleton("bad", (-1, 2, 0), torch.zeros(3, 3), torch.zeros(3, 3, dtype=torch.long))
    with pytest.raises(MetricInputError, match="shape"):
        Skeleton("bad", (-1, 0), torch.zeros(3, 3), torch.zeros(2, 3, dtype=torch.long))


# --- forward kinematics ----------------------------------------------------------------------


def test_rest_pose_is_cumulative_offsets(h36m):
    pos = forward_kinematics(torch.zeros(99, dtype=torch.float64), h36m)
    for j in range(h36m.num_joints):
        expected, a = torch.zeros(3, dtype=torch.float64), j
        while a >= 0:
            expected += h36m.offsets[a]
            a = h36m.parents[a]
        torch.testing.assert_close(pos[j], expected)
    # Right knee (joint 3): hip offset + thigh + shin, by hand from the JSON.
    torch.testing.assert_close(
        pos[3], torch.tensor([-132.948591, -442.894612 - 454.206447, 0.0], dtype=torch.float64)
    )


def test_row_vector_convention_known_value(h36m):
    # Joint 1 rotated 90 degrees about z; its child 2 has offset (0, -L, 0). With row vectors,
    # (0, -L, 0) @ Rz(90) = (-L, 0, 0) (a column-vector FK would give (+L, 0, 0)).
    x = torch.zeros(99, dtype=torch.float64)
    x[col(h36m, 1, 2)] = torch.pi / 2
    pos = forward_kinematics(x, h36m)
    L = 442.894612
    expected = torch.tensor([-132.948591 - L, 0.0, 0.0], dtype=torch.float64)
    torch.testing.assert_close(pos[2], expected, atol=1e-4, rtol=0)  # see note on Rodrigues' eps


def test_accumulated_rotation_is_own_then_parent(h36m):
    # Joint 1 (right hip) by 90 deg about z, joint 2 (knee) by 90 deg about x. The ankle offset
    # v = (0, -L3, 0) goes through R_acc(2) = R2 @ R1: v @ Rx(90) = (0, 0, L3), then
    # @ Rz(90) = (0, 0, L3). (The other order would give (-L3, 0, 0).) The knee itself is at
    # hip + (0, -L2, 0) @ Rz(90) = hip + (-L2, 0, 0).
    x = torch.zeros(99, dtype=torch.float64)
    x[col(h36m, 1, 2)] = torch.pi / 2
    x[col(h36m, 2, 0)] = torch.pi / 2
    pos = forward_kinematics(x, h36m)
    L2, L3 = 442.894612, 454.206447
    expected = torch.tensor([-132.948591 - L2, 0.0, L3], dtype=torch.float64)
    torch.testing.assert_close(pos[3], expected, atol=1e-4, rtol=0)


def test_rotating_one_joint_moves_only_its_descendants(h36m):
    rest = forward_kinematics(torch.zeros(99, dtype=torch.float64), h36m)
    for joint in (2, 12, 17):
        x = torch.zeros(99, dtype=torch.float64)
        x[h36m.expmap_columns[joint]] = torch.tensor([0.4, -0.9, 0.3], dtype=torch.float64)
        moved = (forward_kinematics(x, h36m) - rest).norm(dim=-1) > 1e-6
        below = descendants(h36m, joint)
        # Every descendant whose chain from `joint` has a non-zero offset moves; nothing else.
        assert set(moved.nonzero().flatten().tolist()) <= below
        for j in below:
            chain_length = (rest[j] - rest[joint]).norm()
            assert bool(moved[j]) == bool(chain_length > 1e-6), (joint, j)


def test_bone_lengths_preserved_under_random_rotations(h36m):
    g = torch.Generator().manual_seed(0)
    x = torch.randn(16, 99, generator=g, dtype=torch.float64)
    pos = forward_kinematics(x, h36m)
    for j in range(1, h36m.num_joints):
        bone = (pos[:, j] - pos[:, h36m.parents[j]]).norm(dim=-1)
        torch.testing.assert_close(bone, h36m.offsets[j].norm().expand(16), rtol=1e-6, atol=0)


def test_zero_global_ignores_root_columns_and_false_uses_them(h36m):
    g = torch.Generator().manual_seed(1)
    x = torch.randn(99, generator=g, dtype=torch.float64)
    y = x.clone()
    y[:6] = torch.tensor([10.0, -20.0, 30.0, 0.0, 0.0, 0.0], dtype=torch.float64)
    torch.testing.assert_close(forward_kinematics(x, h36m), forward_kinematics(y, h36m))
    # Without zeroing, a pure root translation shifts every joint by cols 0-2.
    shift = forward_kinematics(y, h36m, zero_global=False) - forward_kinematics(y, h36m)
    expected = torch.tensor([10.0, -20.0, 30.0], dtype=torch.float64).expand(32, 3)
    torch.testing.assert_close(shift, expected)


def test_fk_is_vectorised_over_leading_dims(h36m):
    g = torch.Generator().manual_seed(2)
    x = torch.randn(2, 3, 99, generator=g)
    pos = forward_kinematics(x, h36m)
    assert pos.shape == (2, 3, 32, 3) and pos.dtype == torch.float32
    # float32, and batched matmuls may sum in another order than single ones: positions are in
    # mm, so 1e-4 mm absolute is far below anything the metric can resolve.
    torch.testing.assert_close(pos[1, 2], forward_kinematics(x[1, 2], h36m), rtol=1e-5, atol=1e-4)
    with pytest.raises(MetricInputError, match="99 columns"):
        forward_kinematics(torch.zeros(2, 117), h36m)


def test_yz_swap():
    p = torch.tensor([[1.0, 2.0, 3.0]])
    assert yz_swap(p).tolist() == [[1.0, 3.0, 2.0]]


# --- moving joints ---------------------------------------------------------------------------


def test_moving_joints_h36m_is_the_common_22(h36m):
    joints = moving_joints(h36m, h36m_used())
    assert int(h36m_used().sum()) == 54
    assert joints.tolist() == H36M_MOVING


def test_moving_joints_cmu():
    cmu = Skeleton.load("cmu")
    used = torch.ones(117, dtype=torch.bool)
    used[CMU_IGNORED] = False
    assert int(used.sum()) == 70
    assert moving_joints(cmu, used).tolist() == CMU_MOVING


def test_moving_joints_edge_cases(h36m):
    assert moving_joints(h36m, torch.zeros(99, dtype=torch.bool)).tolist() == []
    # Only the root's columns used: the metric zeroes the root, so nothing moves.
    root_only = torch.zeros(99, dtype=torch.bool)
    root_only[3:6] = True
    assert moving_joints(h36m, root_only).tolist() == []
    with pytest.raises(MetricInputError, match="bool"):
        moving_joints(h36m, torch.ones(99))


# --- MPJPE -----------------------------------------------------------------------------------


def test_mpjpe_known_value(h36m):
    # Flip the right toe (joint 5, offset (0, 0, 75.0) from joint 4) by pi about y at joint 4:
    # only joint 5 moves, by 2 * 74.999437 mm; averaged over the 22 joints.
    gt = torch.zeros(1, 2, 99, dtype=torch.float64)
    pred = gt.clone()
    pred[0, 1, col(h36m, 4, 1)] = torch.pi
    joints = torch.tensor(H36M_MOVING)
    err = mpjpe_per_frame(pred, gt, h36m, joints)
    expected = torch.tensor([[0.0, 2 * 74.999437 / 22]], dtype=torch.float64)
    torch.testing.assert_close(err, expected, rtol=1e-6, atol=1e-9)


def test_mpjpe_metric_accumulates_and_nan_for_missing(h36m):
    g = torch.Generator().manual_seed(3)
    gt = torch.randn(6, 5, 99, generator=g, dtype=torch.float64) * 0.3
    pred = gt + 0.1 * torch.randn(6, 5, 99, generator=g, dtype=torch.float64)
    action = torch.tensor([0, 0, 2, 2, 2, 0])
    joints = moving_joints(h36m, h36m_used())

    split = MPJPE(h36m, joints, num_actions=3, num_frames=5)
    split.update(pred[:2], gt[:2], action[:2])
    split.update(pred[2:], gt[2:], action[2:])
    whole = MPJPE(h36m, joints, num_actions=3, num_frames=5)
    whole.update(pred, gt, action)
    torch.testing.assert_close(split.compute(), whole.compute(), equal_nan=True)

    out = whole.compute()
    per_window = mpjpe_per_frame(pred, gt, h36m, joints)
    torch.testing.assert_close(out[0], per_window[[0, 1, 5]].mean(0))
    torch.testing.assert_close(out[2], per_window[[2, 3, 4]].mean(0))
    assert torch.isnan(out[1]).all()
    assert (out[[0, 2]] > 0).all()


def test_mpjpe_rejects_bad_input(h36m):
    with pytest.raises(MetricInputError, match="joint indices"):
        MPJPE(h36m, torch.tensor([0, 32]), num_actions=1, num_frames=5)
    metric = MPJPE(h36m, torch.tensor(H36M_MOVING), num_actions=1, num_frames=5)
    with pytest.raises(MetricInputError, match="num_frames"):
        metric.update(
            torch.zeros(1, 4, 99), torch.zeros(1, 4, 99), torch.zeros(1, dtype=torch.long)
        )
