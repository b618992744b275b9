"""Linear blend skinning of the canonical skeleton, pure numpy (after smplx's lbs.py).

Shapes: rest_vertices V x 3, weights V x 22 (rows sum to 1), rest_joints 22 x 3, rotations
T x 22 x 4 local (w, x, y, z) quaternions, root T x 3 (pelvis world position). Consistent with
live.kinematics.forward_kinematics: a joint's skinning transform maps its rest position to its
posed position, so identity rotations with root = rest pelvis reproduce the rest mesh.
"""

from __future__ import annotations

import numpy as np

from live.kinematics import forward_kinematics
from live.rotations import quat_to_matrix
from live.skeleton import PARENTS, rest_offsets


def skinning_transforms(rotations: np.ndarray, root: np.ndarray, rest_joints: np.ndarray,
                        parents: np.ndarray = PARENTS) -> np.ndarray:
    """(T, 22, 3, 4) rigid transforms [R | t] taking rest-pose points to posed points per joint."""
    rotations = np.asarray(rotations, np.float64)
    rest = np.asarray(rest_joints, np.float64)
    if rotations.ndim == 2:
        return _single_frame_transforms(rotations, np.asarray(root, np.float64), rest, parents)[None]
    joints, glob = forward_kinematics(rotations, np.asarray(root, np.float64), rest, parents)
    r = quat_to_matrix(glob)  # T x J x 3 x 3
    t = joints - np.einsum("tjab,jb->tja", r, rest)
    return np.concatenate([r, t[..., None]], axis=-1)


def _single_frame_transforms(rotations: np.ndarray, root: np.ndarray, rest: np.ndarray,
                             parents: np.ndarray) -> np.ndarray:
    """One frame: the same transforms with a 3x3 loop (the live path; no per-joint quaternion
    arrays). Equal to the batched path to float precision."""
    local = quat_to_matrix(rotations)
    offsets = rest_offsets(rest)
    glob = np.empty_like(local)
    pos = np.empty_like(rest)
    for j, p in enumerate(parents):
        if p < 0:
            glob[j] = local[j]
            pos[j] = root
        else:
            glob[j] = glob[p] @ local[j]
            pos[j] = pos[p] + glob[p] @ offsets[j]
    out = np.empty((len(parents), 3, 4))
    out[:, :, :3] = glob
    out[:, :, 3] = pos - np.einsum("jab,jb->ja", glob, rest)
    return out


def lbs(rest_vertices: np.ndarray, weights: np.ndarray, rest_joints: np.ndarray, rotations: np.ndarray,
        root: np.ndarray, parents: np.ndarray = PARENTS) -> np.ndarray:
    """Posed vertices (T, V, 3) float32 (T = 1 for a single (22, 4) pose)."""
    g = skinning_transforms(rotations, root, rest_joints, parents).astype(np.float32)  # T x J x 3 x 4
    t_count, j_count = g.shape[:2]
    wt = np.ascontiguousarray(np.asarray(weights, np.float32).T)  # J x V
    vt = np.asarray(rest_vertices, np.float32).T  # 3 x V
    # Blend the 12 transform coefficients of every vertex with one matmul, laid out
    # (column, row) x V so that applying them is four fused multiply-adds on contiguous rows.
    coeffs = np.ascontiguousarray(g.transpose(0, 3, 2, 1)).reshape(t_count * 12, j_count)
    blended = (coeffs @ wt).reshape(t_count, 4, 3, -1)
    out = blended[:, 0] * vt[0] + blended[:, 1] * vt[1] + blended[:, 2] * vt[2] + blended[:, 3]
    return np.ascontiguousarray(out.transpose(0, 2, 1))
