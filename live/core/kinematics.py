"""Forward kinematics of the canonical skeleton, pure numpy: the one place that poses a skeleton.

A pose is a root position (..., 3) plus local rotations (..., 22, 4) (or (..., 22, 3, 3))
applied to a rest skeleton (22, 3) in the canonical T-pose; identity rotations reproduce the
rest skeleton translated so that the pelvis is at the root position. Bones are given either as
rest joints or as their rest offsets from the parent (live.core.skeleton.rest_offsets).

Two forms of the same result, each the arithmetic of the path that uses it (outputs are kept
bit for bit, so neither is rewritten in terms of the other):

* quaternions (``forward_kinematics``, ``joints_from_global_quats``): offline motions, the IMU
  suit;
* rotation matrices (``forward_kinematics_matrices``, ``joints_from_global_matrices``): the
  retargeters, which hold matrices; ``forward_kinematics_frame`` for one frame, the skinning's.

``joints_from_global_*`` pose a skeleton whose global rotations are known (the solvers produce
them) with one product against live.core.skeleton.BONE_ANCESTRY instead of a walk down the tree.
"""

from __future__ import annotations

import numpy as np

from live.core.rotations import quat_conjugate, quat_multiply, quat_normalize, quat_rotate
from live.core.skeleton import BONE_ANCESTRY, LEVELS, NUM_JOINTS, PARENTS, rest_offsets


def global_rotations(rotations: np.ndarray, parents: np.ndarray = PARENTS) -> np.ndarray:
    """Local rotations (..., J, 4) -> global (world) rotations (..., J, 4)."""
    rotations = quat_normalize(np.asarray(rotations, dtype=np.float64))
    out = np.empty_like(rotations)
    for j, p in enumerate(parents):
        out[..., j, :] = rotations[..., j, :] if p < 0 else quat_multiply(out[..., p, :], rotations[..., j, :])
    return out


def local_rotations(glob: np.ndarray) -> np.ndarray:
    """Global rotations (..., 22, 4) -> local rotations relative to the parent (..., 22, 4)."""
    glob = np.asarray(glob, dtype=np.float64)
    loc = glob.copy()
    loc[..., 1:, :] = quat_multiply(quat_conjugate(glob[..., PARENTS[1:], :]), glob[..., 1:, :])
    return loc


def local_matrices(glob: np.ndarray) -> np.ndarray:
    """Global rotation matrices (..., 22, 3, 3) -> local ones relative to the parent, G_p^T G_j."""
    loc = np.empty_like(glob)
    loc[..., 0, :, :] = glob[..., 0, :, :]
    loc[..., 1:, :, :] = np.swapaxes(glob[..., PARENTS[1:], :, :], -1, -2) @ glob[..., 1:, :, :]
    return loc


def forward_kinematics(
    rotations: np.ndarray,
    root: np.ndarray,
    rest_joints: np.ndarray,
    parents: np.ndarray = PARENTS,
) -> tuple[np.ndarray, np.ndarray]:
    """World joint positions and global rotations of posed skeletons.

    rotations: (..., J, 4) local quaternions; root: (..., 3) pelvis world position;
    rest_joints: (J, 3) T-pose joint positions. Returns joints (..., J, 3), global (..., J, 4).
    Parents must come before their children.
    """
    glob = global_rotations(rotations, parents)
    offsets = rest_offsets(np.asarray(rest_joints, dtype=np.float64))
    joints = np.empty(glob.shape[:-1] + (3,), dtype=np.float64)
    joints[..., 0, :] = np.asarray(root, dtype=np.float64)
    for j, p in enumerate(parents):
        if p >= 0:
            joints[..., j, :] = joints[..., p, :] + quat_rotate(glob[..., p, :], offsets[j])
    return joints, glob


def forward_kinematics_matrices(
    local: np.ndarray, root: np.ndarray, offsets: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``forward_kinematics`` on rotation matrices, one tree level at a time.

    local (..., 22, 3, 3) local rotations; root (..., 3); offsets (22, 3) rest offsets from the
    parent. Returns joints (..., 22, 3), global rotations (..., 22, 3, 3).
    """
    lead = local.shape[:-3]
    loc = local.reshape((-1, NUM_JOINTS, 3, 3))
    glob = np.empty_like(loc)
    pos = np.empty((loc.shape[0], NUM_JOINTS, 3))
    glob[:, 0] = loc[:, 0]
    pos[:, 0] = np.reshape(root, (-1, 3))
    for level in LEVELS[1:]:
        p = PARENTS[level]
        glob[:, level] = glob[:, p] @ loc[:, level]
        pos[:, level] = pos[:, p] + np.einsum("nkij,kj->nki", glob[:, p], offsets[level])
    return pos.reshape(lead + (NUM_JOINTS, 3)), glob.reshape(lead + (NUM_JOINTS, 3, 3))


def forward_kinematics_frame(
    local: np.ndarray, root: np.ndarray, offsets: np.ndarray, parents: np.ndarray = PARENTS
) -> tuple[np.ndarray, np.ndarray]:
    """One frame of ``forward_kinematics_matrices`` joint by joint on 3x3 products (no batch
    axis to index: the per-frame skinning of live.body.skinning). local (J, 3, 3), root (3,),
    offsets (J, 3); returns joints (J, 3), global rotations (J, 3, 3)."""
    glob = np.empty_like(local)
    pos = np.empty((len(parents), 3))
    for j, p in enumerate(parents):
        if p < 0:
            glob[j] = local[j]
            pos[j] = root
        else:
            glob[j] = glob[p] @ local[j]
            pos[j] = pos[p] + glob[p] @ offsets[j]
    return pos, glob


def joints_from_global_matrices(glob: np.ndarray, root: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Joint positions (..., 22, 3) of a pose given as global rotation matrices (..., 22, 3, 3):
    each bone's rest offset (offsets (22, 3), from the parent) turned by its parent's global
    rotation, summed down the tree from the root (..., 3). The joints of
    ``forward_kinematics_matrices`` of the matching local rotations."""
    lead = glob.shape[:-3]
    g = glob.reshape((-1, NUM_JOINTS, 3, 3))
    bones = np.einsum("nkij,kj->nki", g[:, PARENTS[1:]], offsets[1:])  # (N, 21, 3)
    joints = np.asarray(root, np.float64).reshape(-1, 3)[:, None, :] + BONE_ANCESTRY @ bones
    return joints.reshape(lead + (NUM_JOINTS, 3))


def joints_from_global_quats(glob: np.ndarray, root: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """World joints (..., 22, 3) from global rotations as quaternions (..., 22, 4), the root
    (..., 3) and the rest offsets from the parent (22, 3); the joints of ``forward_kinematics``
    of the matching local rotations."""
    bones = quat_rotate(np.asarray(glob, np.float64)[..., PARENTS[1:], :], offsets[1:])
    return np.asarray(root, np.float64)[..., None, :] + np.einsum("jk,...kd->...jd", BONE_ANCESTRY, bones)
