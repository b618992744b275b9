"""Forward kinematics of BVH skeletons (any rig): world joint positions and global rotation
matrices per frame, the zero-rotation rest pose, and the skeleton's span (tree diameter)."""

from __future__ import annotations

import numpy as np

from live.io.bvh_clip import BvhClip, BvhSkeleton


def bvh_forward_kinematics(clip: BvhClip, *, end_sites: bool = False
                           ) -> tuple[np.ndarray, np.ndarray]:
    """World joint positions (T, J, 3) and global rotations (T, J, 3, 3) of every frame.

    With ``end_sites`` the positions are (T, J + E, 3) and rotations (T, J + E, 3, 3): end sites
    follow the joints, in ``skeleton.end_names()`` order, with their parent's rotation.
    """
    return skeleton_forward_kinematics(clip.skeleton, clip.local_rotations(),
                                       clip.local_translations(), end_sites=end_sites)


def skeleton_forward_kinematics(skeleton: BvhSkeleton, local_rot: np.ndarray,
                                local_trans: np.ndarray, *, end_sites: bool = False
                                ) -> tuple[np.ndarray, np.ndarray]:
    """FK from local rotations (T, J, 3, 3) and local translations (T, J, 3)."""
    ne = len(skeleton.end_parents) if end_sites else 0
    # Per-joint contiguous (T, 3, 3) blocks: strided views of a (T, J, 3, 3) array make
    # numpy's small-matrix products several times slower.
    rot = np.ascontiguousarray(np.moveaxis(local_rot, 1, 0))
    trans = np.ascontiguousarray(np.moveaxis(local_trans, 1, 0))
    glob: list[np.ndarray] = []
    pos: list[np.ndarray] = []
    for j, p in enumerate(skeleton.parents):
        if p < 0:
            glob.append(rot[j])
            pos.append(trans[j])
        else:
            glob.append(glob[p] @ rot[j])
            pos.append(pos[p] + np.einsum("tij,tj->ti", glob[p], trans[j]))
    for e in range(ne):
        p = skeleton.end_parents[e]
        glob.append(glob[p])
        pos.append(pos[p] + glob[p] @ skeleton.end_offsets[e])
    return np.stack(pos, axis=1), np.stack(glob, axis=1)


def rest_positions(skeleton: BvhSkeleton, *, end_sites: bool = False) -> np.ndarray:
    """(J, 3) (or (J + E, 3)) world positions of the zero-rotation pose, root at its offset."""
    n = skeleton.num_joints
    pos, _ = skeleton_forward_kinematics(
        skeleton, np.broadcast_to(np.eye(3), (1, n, 3, 3)), skeleton.offsets[None],
        end_sites=end_sites)
    return pos[0]


def skeleton_span(skeleton: BvhSkeleton) -> float:
    """Longest leaf-to-leaf path length through the hierarchy (tree diameter), file units."""
    n = skeleton.num_joints
    lengths = np.linalg.norm(skeleton.offsets, axis=1)
    down = np.zeros(n)  # longest path from each joint down to a leaf of its subtree
    for e, p in enumerate(skeleton.end_parents):
        down[p] = max(down[p], float(np.linalg.norm(skeleton.end_offsets[e])))
    best = 0.0
    for j in range(n - 1, 0, -1):  # children come after parents in file order
        p = skeleton.parents[j]
        cand = down[j] + lengths[j]
        best = max(best, down[p] + cand)  # joins the best branch seen so far at p
        down[p] = max(down[p], cand)
    return float(max(best, down[0]))
