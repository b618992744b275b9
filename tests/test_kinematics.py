"""Forward kinematics (live.core.kinematics) in its quaternion and matrix forms agree with each
other, batched and frame by frame, with and without the local rotations; the topology tables of
live.core.skeleton agree with PARENTS; the heading helpers agree with the rotations."""

from __future__ import annotations

import numpy as np
import pytest

from live.core import heading
from live.core import vec3 as v3
from live.core.kinematics import (
    forward_kinematics,
    forward_kinematics_frame,
    forward_kinematics_matrices,
    global_rotations,
    joints_from_global_matrices,
    joints_from_global_quats,
    local_matrices,
    local_rotations,
)
from live.core.rotations import matrix_to_quat, quat_from_axis_angle, quat_multiply, quat_rotate, quat_to_matrix
from live.core.skeleton import (
    ANCESTORS,
    BONE_ANCESTRY,
    BONES,
    CHILDREN,
    DEPTHS,
    LEAVES,
    LEVELS,
    NUM_JOINTS,
    PARENTS,
    ancestors_of,
    default_rest_joints,
    joint_depths,
    joints_from_offsets,
    rest_offsets,
)

RNG = np.random.default_rng(11)
REST = default_rest_joints(1.68).astype(np.float64)
OFFSETS = rest_offsets(REST)


def _pose(n: int) -> tuple[np.ndarray, np.ndarray]:
    return quat_from_axis_angle(RNG.normal(0, 0.7, (n, NUM_JOINTS, 3))), RNG.normal(0, 1, (n, 3))


def test_quaternion_and_matrix_fk_agree():
    rot, root = _pose(6)
    joints, glob = forward_kinematics(rot, root, REST)
    m_joints, m_glob = forward_kinematics_matrices(quat_to_matrix(rot), root, OFFSETS)
    np.testing.assert_allclose(m_joints, joints, atol=1e-12)
    np.testing.assert_allclose(m_glob, quat_to_matrix(glob), atol=1e-12)


def test_identity_rotations_give_the_rest_skeleton_at_the_root():
    root = np.array([0.3, 0.9, -1.2])
    joints, _ = forward_kinematics(np.tile([1.0, 0, 0, 0], (NUM_JOINTS, 1)), root, REST)
    np.testing.assert_allclose(joints, REST - REST[0] + root, atol=1e-12)
    pos, _ = forward_kinematics_matrices(np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3)), root, OFFSETS)
    np.testing.assert_allclose(pos, joints, atol=1e-12)


def test_batched_equals_frame_by_frame():
    rot, root = _pose(4)
    loc = quat_to_matrix(rot)
    joints, glob = forward_kinematics(rot, root, REST)
    m_joints, m_glob = forward_kinematics_matrices(loc, root, OFFSETS)
    for t in range(len(rot)):
        one, one_glob = forward_kinematics(rot[t], root[t], REST)
        np.testing.assert_array_equal(one, joints[t])
        np.testing.assert_array_equal(one_glob, glob[t])
        m_one, m_one_glob = forward_kinematics_matrices(loc[t], root[t], OFFSETS)
        np.testing.assert_array_equal(m_one, m_joints[t])
        np.testing.assert_array_equal(m_one_glob, m_glob[t])
        np.testing.assert_array_equal(joints_from_global_quats(glob[t], root[t], OFFSETS),
                                      joints_from_global_quats(glob, root, OFFSETS)[t])
        np.testing.assert_array_equal(joints_from_global_matrices(m_glob[t], root[t], OFFSETS),
                                      joints_from_global_matrices(m_glob, root, OFFSETS)[t])
        # The joint-by-joint single-frame form: the same pose, its own rounding.
        f_joints, f_glob = forward_kinematics_frame(loc[t], root[t], OFFSETS)
        np.testing.assert_allclose(f_joints, m_joints[t], atol=1e-12)
        np.testing.assert_allclose(f_glob, m_glob[t], atol=1e-12)
    # Any leading shape.
    two = forward_kinematics_matrices(loc.reshape(2, 2, NUM_JOINTS, 3, 3), root.reshape(2, 2, 3), OFFSETS)[0]
    np.testing.assert_array_equal(two.reshape(4, NUM_JOINTS, 3), m_joints)


def test_positions_from_global_rotations_are_forward_kinematics():
    rot, root = _pose(5)
    joints, glob = forward_kinematics(rot, root, REST)
    np.testing.assert_allclose(joints_from_global_quats(glob, root, OFFSETS), joints, atol=1e-12)
    m_joints, m_glob = forward_kinematics_matrices(quat_to_matrix(rot), root, OFFSETS)
    np.testing.assert_allclose(joints_from_global_matrices(m_glob, root, OFFSETS), m_joints, atol=1e-12)


def test_local_and_global_rotations_are_inverse():
    rot, _ = _pose(3)
    glob = global_rotations(rot)
    back = local_rotations(glob)
    np.testing.assert_allclose(np.abs(np.sum(back * rot, -1)), 1.0, atol=1e-12)  # up to sign
    _, m_glob = forward_kinematics_matrices(quat_to_matrix(rot), np.zeros((3, 3)), OFFSETS)
    np.testing.assert_allclose(local_matrices(m_glob), quat_to_matrix(rot), atol=1e-12)
    np.testing.assert_allclose(local_matrices(m_glob[0]), quat_to_matrix(rot[0]), atol=1e-12)


def test_topology_tables_agree_with_parents():
    assert PARENTS[0] == -1 and all(PARENTS[j] < j for j in range(1, NUM_JOINTS))
    assert ANCESTORS[0] == ()
    for j in range(1, NUM_JOINTS):
        chain = ANCESTORS[j]
        assert chain[0] == PARENTS[j] and chain[-1] == 0  # nearest first, ends at the root
        assert all(PARENTS[a] == b for a, b in zip(chain, chain[1:]))
        assert len(chain) == DEPTHS[j] == DEPTHS[PARENTS[j]] + 1  # levels increase along chains
        assert chain == ancestors_of(PARENTS, j)
        # The ancestry matrix marks exactly the bones on the path root -> j.
        assert set(np.flatnonzero(BONE_ANCESTRY[j]) + 1) == {j, *chain[:-1]}
    assert not BONE_ANCESTRY[0].any()
    np.testing.assert_array_equal(joint_depths(PARENTS), DEPTHS)
    assert sorted(np.concatenate(LEVELS).tolist()) == list(range(NUM_JOINTS))
    for d, level in enumerate(LEVELS):
        assert (DEPTHS[level] == d).all()
    for j in range(NUM_JOINTS):
        assert set(CHILDREN[j]) == set(np.flatnonzero(PARENTS == j).tolist())
    assert LEAVES == tuple(j for j in range(NUM_JOINTS) if j not in set(PARENTS.tolist()))
    assert len(BONES) == NUM_JOINTS - 1 and all(PARENTS[c] == p for p, c in BONES)


def test_joints_from_offsets_inverts_rest_offsets():
    np.testing.assert_array_equal(joints_from_offsets(OFFSETS), REST)
    rest32 = default_rest_joints()
    np.testing.assert_allclose(joints_from_offsets(rest_offsets(rest32)), rest32, atol=1e-6)


def test_heading_helpers():
    a = RNG.uniform(-np.pi, np.pi, 20)
    q = heading.yaw_quat(a)
    np.testing.assert_allclose(heading.wrap_angle(heading.yaw_of(q)), a, atol=1e-12)
    np.testing.assert_allclose(heading.yaw_matrix(a), quat_to_matrix(q), atol=1e-12)
    # Any rotation's heading is that of its yaw part: the swing about a horizontal axis is removed.
    swing = quat_from_axis_angle(np.stack([RNG.normal(size=20), np.zeros(20), RNG.normal(size=20)], -1) * 0.3)
    np.testing.assert_allclose(heading.wrap_angle(heading.yaw_of(quat_multiply(q, swing)) - a), 0.0, atol=1e-12)
    # A direction's heading: the yaw taking +z to it.
    d = quat_rotate(q, np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(heading.direction_yaw(d), a, atol=1e-12)
    angle, evidence = heading.yaw_between(d[:5], quat_rotate(heading.yaw_quat(0.4), d[:5]), np.ones(5))
    assert angle == pytest.approx(0.4) and evidence == pytest.approx(5.0)
    for x in (-7.0, -np.pi, 0.0, 3.0, 12.5):
        assert v3.wrap_angle(x) == float(heading.wrap_angle(x))


def test_scalar_quaternions_agree_with_numpy():
    a, b = quat_from_axis_angle(RNG.normal(size=(2, 3)))
    np.testing.assert_allclose(v3.quat_mul(a.tolist(), b.tolist()), quat_multiply(a, b), atol=1e-15)
    assert v3.quat_mul(v3.quat_conj(a.tolist()), a.tolist()) == pytest.approx((1.0, 0.0, 0.0, 0.0))
    assert v3.quat_norm((1.0, 2.0, 2.0, 4.0)) == 5.0
    for q in quat_from_axis_angle(RNG.normal(size=(50, 3)) * 2.0):
        got = np.array(v3.quat_from_matrix(quat_to_matrix(q).tolist()))
        np.testing.assert_allclose(got * np.sign(got[0]), matrix_to_quat(quat_to_matrix(q)), atol=1e-12)
