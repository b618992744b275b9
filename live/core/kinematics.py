"""Forward kinematics of the canonical skeleton, pure numpy.

A pose is a root position (T, 3) plus local rotations (T, 22, 4) applied to a rest skeleton
(22, 3) in the canonical T-pose; identity rotations reproduce the rest skeleton translated so
that the pelvis is at the root position.
"""

from __future__ import annotations

import numpy as np

from live.core.rotations import quat_multiply, quat_normalize, quat_rotate
from live.core.skeleton import PARENTS, rest_offsets


def global_rotations(rotations: np.ndarray, parents: np.ndarray = PARENTS) -> np.ndarray:
    """Local rotations (..., J, 4) -> global (world) rotations (..., J, 4)."""
    rotations = quat_normalize(np.asarray(rotations, dtype=np.float64))
    out = np.empty_like(rotations)
    for j, p in enumerate(parents):
        out[..., j, :] = rotations[..., j, :] if p < 0 else quat_multiply(out[..., p, :], rotations[..., j, :])
    return out


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
