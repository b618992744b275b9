"""The canonical 22-joint skeleton (SMPL body order), the one place that defines it.

Shapes: joint positions (..., 22, 3) in metres; local rotations (..., 22, 4) as (w, x, y, z)
quaternions, each relative to its parent; a rest skeleton is (22, 3) world joint positions in the
canonical T-pose (facing +z, y up, left arm along +x, feet on y = 0). See ../shared/CONVENTIONS.md.
"""

from __future__ import annotations

import numpy as np

JOINT_NAMES: tuple[str, ...] = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2",
    "left_ankle", "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar",
    "right_collar", "head", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow",
    "left_wrist", "right_wrist",
)
NUM_JOINTS = len(JOINT_NAMES)
PARENTS: np.ndarray = np.array(
    [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19], dtype=np.int32
)
JOINT_INDEX: dict[str, int] = {name: i for i, name in enumerate(JOINT_NAMES)}
#: The joints a close-up (a seated performer, legs out of view) is scored on: pelvis, spine,
#: neck, head, collars and arms.
UPPER_BODY_JOINTS: tuple[int, ...] = (0, 3, 6, 9, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21)

#: (parent, child) pairs, one per bone, for drawing and bone-length checks.
BONES: tuple[tuple[int, int], ...] = tuple((int(p), c) for c, p in enumerate(PARENTS) if p >= 0)

#: Index permutation that swaps left and right joints (mirror augmentation, flip guard).
LEFT_RIGHT_SWAP: np.ndarray = np.array(
    [JOINT_INDEX[n.replace("left_", "#").replace("right_", "left_").replace("#", "right_")]
     for n in JOINT_NAMES],
    dtype=np.int64,
)


# ----------------------------------------------------------------------------- topology
# Any tree given as a parents array (-1 for the root, parents before their children): the
# canonical tables below, and the rigs of BVH files.


def joint_depths(parents: np.ndarray) -> np.ndarray:
    """(J,) number of bones between each joint and the root (the root is at depth 0)."""
    depth = np.zeros(len(parents), dtype=np.int64)
    for j, p in enumerate(parents):
        if p >= 0:
            depth[j] = depth[p] + 1
    return depth


def ancestors_of(parents: np.ndarray, j: int) -> tuple[int, ...]:
    """Joints above j, nearest first: (parent, grandparent, ..., root); () for the root."""
    out = []
    while parents[j] >= 0:
        j = int(parents[j])
        out.append(j)
    return tuple(out)


#: Children of each joint; leaves (feet, head, wrists) carry no bone direction of their own.
CHILDREN: tuple[tuple[int, ...], ...] = tuple(
    tuple(int(c) for c in np.flatnonzero(PARENTS == j)) for j in range(NUM_JOINTS)
)
#: Joints without children.
LEAVES: tuple[int, ...] = tuple(j for j in range(NUM_JOINTS) if not CHILDREN[j])
#: (22,) depth of each joint in the tree (pelvis 0).
DEPTHS: np.ndarray = joint_depths(PARENTS)
#: Joint indices per tree level, LEVELS[d] = the joints at depth d: a level is a batch whose
#: parents are all in earlier levels (forward kinematics one level at a time).
LEVELS: tuple[np.ndarray, ...] = tuple(np.flatnonzero(DEPTHS == d) for d in range(int(DEPTHS.max()) + 1))
#: ANCESTORS[j]: the joints above j, nearest first, ending at the pelvis (() for the pelvis).
ANCESTORS: tuple[tuple[int, ...], ...] = tuple(ancestors_of(PARENTS, j) for j in range(NUM_JOINTS))


def _bone_ancestry() -> np.ndarray:
    a = np.zeros((NUM_JOINTS, NUM_JOINTS - 1))
    for j in range(1, NUM_JOINTS):
        for k in (j,) + ANCESTORS[j][:-1]:
            a[j, k - 1] = 1.0
    return a


#: (22, 21): BONE_ANCESTRY[j, k - 1] = 1 where bone k (from joint k's parent to joint k) lies on
#: the path from the root to joint j, so joints = root + BONE_ANCESTRY @ bone vectors (one
#: product instead of a walk down the tree).
BONE_ANCESTRY: np.ndarray = _bone_ancestry()


def rest_offsets(rest_joints: np.ndarray) -> np.ndarray:
    """(22, 3) rest joint positions -> (22, 3) offsets from each parent (root keeps its position)."""
    rest_joints = np.asarray(rest_joints)
    offsets = rest_joints.copy()
    offsets[1:] = rest_joints[1:] - rest_joints[PARENTS[1:]]
    return offsets


def joints_from_offsets(offsets: np.ndarray) -> np.ndarray:
    """Inverse of ``rest_offsets``: (22, 3) offsets from each parent (row 0: the root's position)
    -> (22, 3) joint positions, each its parent's plus its offset."""
    offsets = np.asarray(offsets)
    joints = np.empty_like(offsets)
    joints[0] = offsets[0]
    for p, c in BONES:
        joints[c] = joints[p] + offsets[c]
    return joints


def bone_lengths(joints: np.ndarray) -> np.ndarray:
    """(..., 22, 3) joint positions -> (..., 21) bone lengths, in BONES order."""
    joints = np.asarray(joints)
    child = np.array([c for _, c in BONES])
    parent = np.array([p for p, _ in BONES])
    return np.linalg.norm(joints[..., child, :] - joints[..., parent, :], axis=-1)


def pelvis_height(rest_joints: np.ndarray) -> float:
    """Rest pelvis height (y of joint 0 in the T-pose), the leg length used to scale root motion."""
    return float(np.asarray(rest_joints)[0, 1])


def default_rest_joints(height: float = 1.75) -> np.ndarray:
    """A generic adult T-pose skeleton scaled to ``height`` metres (for tests and fallbacks).

    Proportions are typical adult anthropometry; real bodies come from the body library.
    """
    s = height / 1.75
    j = np.zeros((NUM_JOINTS, 3), dtype=np.float64)
    j[0] = (0.0, 0.95, 0.0)
    j[1] = (0.09, 0.87, 0.0)
    j[2] = (-0.09, 0.87, 0.0)
    j[3] = (0.0, 1.06, -0.01)
    # Legs straight: knee and ankle directly below the hip (the T-pose of CONVENTIONS.md).
    j[4] = (0.09, 0.48, 0.0)
    j[5] = (-0.09, 0.48, 0.0)
    j[6] = (0.0, 1.19, 0.0)
    j[7] = (0.09, 0.08, 0.0)
    j[8] = (-0.09, 0.08, 0.0)
    j[9] = (0.0, 1.25, 0.01)
    j[10] = (0.10, 0.02, 0.13)
    j[11] = (-0.10, 0.02, 0.13)
    j[12] = (0.0, 1.47, -0.01)
    j[13] = (0.07, 1.39, -0.01)
    j[14] = (-0.07, 1.39, -0.01)
    j[15] = (0.0, 1.55, 0.03)
    j[16] = (0.18, 1.41, -0.02)
    j[17] = (-0.18, 1.41, -0.02)
    j[18] = (0.44, 1.41, -0.02)
    j[19] = (-0.44, 1.41, -0.02)
    j[20] = (0.69, 1.41, -0.02)
    j[21] = (-0.69, 1.41, -0.02)
    return (j * s).astype(np.float32)
