"""Linear blend skinning of the canonical skeleton, pure numpy (after smplx's lbs.py).

Shapes: rest_vertices V x 3, weights V x 22 (rows sum to 1), rest_joints 22 x 3, rotations
T x 22 x 4 local (w, x, y, z) quaternions, root T x 3 (pelvis world position). Consistent with
live.core.kinematics.forward_kinematics: a joint's skinning transform maps its rest position to its
posed position, so identity rotations with root = rest pelvis reproduce the rest mesh.
"""

from __future__ import annotations

import threading

import numpy as np

from live.core.kinematics import forward_kinematics, forward_kinematics_frame
from live.core.rotations import quat_to_matrix
from live.core.skeleton import PARENTS, rest_offsets

# OpenBLAS runs a GEMM on one thread when m x n x k <= 65536 x GEMM_MULTITHREAD_THRESHOLD (4).
_BLAS_SINGLE_THREAD_MNK = 4 * 65536

_LAYOUT_LOCK = threading.Lock()
_LAYOUTS: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # id(array) -> (array, its float32 transpose)


def _transposed(a: np.ndarray) -> np.ndarray:
    """a.T as a C-contiguous float32 array (V x K -> K x V).

    Memoised for read-only float32 arrays that own their data (loaded bodies): those cannot
    change, and the live loop skins the same body every frame, where the copy would cost 15% of
    the frame. The memo holds the array itself, so its id cannot be reused while cached."""
    a = np.asarray(a)
    if a.flags.writeable or a.base is not None or a.dtype != np.float32:
        return np.ascontiguousarray(np.asarray(a, np.float32).T)
    with _LAYOUT_LOCK:
        hit = _LAYOUTS.get(id(a))
        if hit is not None and hit[0] is a:
            return hit[1]
        out = np.ascontiguousarray(a.T)
        out.flags.writeable = False
        if len(_LAYOUTS) >= 16:
            _LAYOUTS.pop(next(iter(_LAYOUTS)))
        _LAYOUTS[id(a)] = (a, out)
        return out


def skinning_transforms(rotations: np.ndarray, root: np.ndarray, rest_joints: np.ndarray,
                        parents: np.ndarray = PARENTS) -> np.ndarray:
    """(T, 22, 3, 4) rigid transforms [R | t] taking rest-pose points to posed points per joint."""
    rotations = np.asarray(rotations, np.float64)
    rest = np.asarray(rest_joints, np.float64)
    if rotations.ndim == 2 or (rotations.ndim == 3 and len(rotations) == 1):
        return _single_frame_transforms(rotations.reshape(-1, 4), np.asarray(root, np.float64).reshape(3),
                                        rest, parents)[None]
    joints, glob = forward_kinematics(rotations, np.asarray(root, np.float64), rest, parents)
    return pose_transforms(quat_to_matrix(glob), joints, rest)


def _single_frame_transforms(rotations: np.ndarray, root: np.ndarray, rest: np.ndarray,
                             parents: np.ndarray) -> np.ndarray:
    """One frame: the same transforms with a 3x3 loop (the live path; no per-joint quaternion
    arrays). Equal to the batched path to float precision."""
    pos, glob = forward_kinematics_frame(quat_to_matrix(rotations), root, rest_offsets(rest), parents)
    return pose_transforms(glob, pos, rest)


def pose_transforms(global_rotations: np.ndarray, joints: np.ndarray, rest_joints: np.ndarray) -> np.ndarray:
    """(..., 22, 3, 4) skinning transforms [G | p - G r] of a pose given as global rotation
    matrices (..., 22, 3, 3) and joint positions (..., 22, 3): what the retargeters hold, so the
    live stage skins with no quaternion round trip and no second forward kinematics."""
    g = np.asarray(global_rotations, np.float64)
    out = np.empty(g.shape[:-1] + (4,))
    out[..., :3] = g
    out[..., 3] = np.asarray(joints, np.float64) - np.einsum("...jab,jb->...ja", g, np.asarray(rest_joints, np.float64))
    return out


def lbs(rest_vertices: np.ndarray, weights: np.ndarray, rest_joints: np.ndarray, rotations: np.ndarray,
        root: np.ndarray, parents: np.ndarray = PARENTS) -> np.ndarray:
    """Posed vertices (T, V, 3) float32 (T = 1 for a single (22, 4) pose)."""
    return skin(rest_vertices, weights, skinning_transforms(rotations, root, rest_joints, parents))


def skin(rest_vertices: np.ndarray, weights: np.ndarray, transforms: np.ndarray) -> np.ndarray:
    """Posed vertices (T, V, 3) float32 from skinning transforms (T, 22, 3, 4)."""
    g = np.asarray(transforms, np.float32)
    t_count, j_count = g.shape[:2]
    wt = _transposed(weights)  # J x V
    vt = _transposed(rest_vertices)  # 3 x V
    # Blend the 12 transform coefficients of every vertex with one matmul, laid out
    # (column, row) x V so that applying them is four fused multiply-adds on contiguous rows.
    coeffs = np.ascontiguousarray(g.transpose(0, 3, 2, 1)).reshape(t_count * 12, j_count)
    if t_count == 1:
        # One frame (the live case): BLAS on column blocks small enough that OpenBLAS never
        # threads them (m n k <= 4 x 65536). A 12 x 22 by 22 x V product is too small for BLAS
        # threads, which on a busy 2-core machine cost 20x (83 instead of 1,700 frames/s); the
        # blocks run single-threaded at a third of einsum's own loop (0.13 against 0.34 ms for
        # the 7k-vertex product; benchmarks/bench_lbs.py: 1,100 -> 1,550 frames/s for lbs()).
        blended = np.empty((12, wt.shape[1]), np.float32)
        block = max(_BLAS_SINGLE_THREAD_MNK // (12 * j_count), 1)
        for a in range(0, wt.shape[1], block):
            np.matmul(coeffs, wt[:, a:a + block], out=blended[:, a:a + block])
        blended = blended.reshape(1, 4, 3, -1)
    else:
        blended = (coeffs @ wt).reshape(t_count, 4, 3, -1)
    out = blended[:, 0] * vt[0] + blended[:, 1] * vt[1] + blended[:, 2] * vt[2] + blended[:, 3]
    return np.ascontiguousarray(out.transpose(0, 2, 1))
