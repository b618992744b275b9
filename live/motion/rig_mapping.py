"""Map any BVH rig onto the canonical 22-joint skeleton: positions and local rotations
(``map_clip``; ``load_motion`` reads a BVH file and maps it).

Where each canonical joint is on the source rig comes from a ``RigTable``: a known rig's
(live/motion/rig_tables.py) or one built from joint names and the hierarchy
(live/motion/auto_mapping.py).

Rotations. Bone directions and twist come from the source's global joint rotations G(t):
for canonical joint j with source a, Q_j(t) = G_a(t) G_a(ref)^T R_j, where R_j is the
canonical frame of j in a reference pose (the rig's zero-rotation pose, or the clip frame most
like a T-pose when the rest pose is far from one, e.g. CC_Base whose rest has every bone along
+y). R_j rotates the canonical T-pose onto the reference pose with the least swing per bone, so
A-poses and rotated joint frames are corrected. Each Q_j is then swung so that its bone points
exactly at the mapped child (joints with one child) or fitted to all children (pelvis and
spine3, by Kabsch). Local rotations are Q_parent^T Q_j; FK of (rotations, root, rest_joints)
gives ``Motion.joints``. The rest skeleton is the clip's own bone lengths along the canonical
T-pose directions of ``default_rest_joints`` (the pelvis and spine3 branches keep the clip's
layout in their own frame), feet on the floor.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from live.core.errors import FormatError
from live.core.kinematics import forward_kinematics, local_matrices
from live.core.rotations import matrix_to_quat, quat_between, quat_to_matrix
from live.core.skeleton import CHILDREN, JOINT_NAMES, NUM_JOINTS, PARENTS, default_rest_joints, joints_from_offsets
from live.io.bvh_clip import BvhClip, BvhSkeleton
from live.io.bvh_kinematics import bvh_forward_kinematics, rest_positions
from live.io.bvh_reader import read_bvh
from live.motion.auto_mapping import auto_mapping
from live.motion.clips import Motion
from live.motion.rig_tables import TABLES, RigTable, detect_rig, spec_names

_DEFAULT_REST = default_rest_joints().astype(np.float64)
_DEGENERATE = np.deg2rad(150.0)  # a bone this far from its T-pose direction has no clear twist


def load_motion(path: str | Path, *, rig: str | None = None, scale: float | str | None = None,
                reference: str | int = "auto") -> Motion:
    """Read a BVH file (any rig, lengths converted to metres) and map it onto the canonical
    skeleton, every frame kept. ``scale``: metres per file unit, a unit name, or None to guess it.
    To use a clip as a performance, see ``live.motion.cleaning.trim_bind_pose``."""
    clip = read_bvh(path, scale="auto" if scale is None else scale)
    return map_clip(clip, rig, reference=reference)


def map_clip(clip: BvhClip, rig: str | RigTable | None = None, *,
             reference: str | int = "auto") -> Motion:
    """Map a clip (lengths already in metres) onto the canonical 22 joints.

    rig: a TABLES name, a RigTable, "auto", or None to detect it. reference: "auto" (the
    zero-rotation pose if it is near a T-pose, else the most T-pose-like frame), "rest", or a
    frame index: the pose that defines each bone's twist (see module docstring).
    """
    table = _resolve_table(clip.skeleton, rig)
    if clip.num_frames == 0:
        raise FormatError("the clip has no frames", path=clip.name or None)
    a, b, t = _spec_arrays(clip.skeleton, table)
    pos, glob = bvh_forward_kinematics(clip, end_sites=True)
    src = pos[:, a] * (1 - t)[:, None] + pos[:, b] * t[:, None]  # (T, 22, 3)
    src_rot = glob[:, a]  # (T, 22, 3, 3)

    rest = rest_positions(clip.skeleton, end_sites=True)
    rest_src = rest[a] * (1 - t)[:, None] + rest[b] * t[:, None]
    if table.rest_is_tpose and reference in ("auto", "rest"):
        ref_x, ref_rot = rest_src, np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3))
        frames = np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3))
    else:
        ref_x, ref_rot, frames = _choose_reference(src, src_rot, rest_src, reference)
    offsets = _fit_branches(src, _rest_offsets(ref_x, frames, table.name))
    correction = np.swapaxes(ref_rot, -1, -2) @ frames  # (22, 3, 3), constant per joint
    q = _global_frames(src, src_rot @ correction, offsets)
    rotations = matrix_to_quat(local_matrices(q)).astype(np.float32)
    rest_joints = _rest_from_offsets(offsets).astype(np.float32)
    root = src[:, 0].astype(np.float32)
    joints, _ = forward_kinematics(rotations, root, rest_joints)
    return Motion(name=clip.name, fps=clip.fps, joints=joints.astype(np.float32),
                  rotations=rotations, root=root, rest_joints=rest_joints, source_rig=table.name)


def source_joints(clip: BvhClip, rig: str | RigTable | None = None) -> np.ndarray:
    """(T, 22, 3) the mapped source points themselves (before the canonical refit), for checks."""
    table = _resolve_table(clip.skeleton, rig)
    a, b, t = _spec_arrays(clip.skeleton, table)
    pos, _ = bvh_forward_kinematics(clip, end_sites=True)
    return pos[:, a] * (1 - t)[:, None] + pos[:, b] * t[:, None]


def _resolve_table(skeleton: BvhSkeleton, rig: str | RigTable | None) -> RigTable:
    if isinstance(rig, RigTable):
        table = rig
    else:
        name = rig or detect_rig(skeleton)
        if name == "auto":
            return auto_mapping(skeleton)
        if name not in TABLES:
            raise FormatError(f"unknown rig {name!r} (known: {', '.join(TABLES)}, auto)")
        table = TABLES[name]
    have = set(skeleton.names) | set(skeleton.end_names())
    lost = sorted({n for s in table.joints.values() for n in spec_names(s) if n not in have})
    if lost:
        raise FormatError(f"rig {table.name!r} does not fit: no joints {', '.join(lost)}")
    return table


def _spec_arrays(skeleton: BvhSkeleton, table: RigTable) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    index = {n: i for i, n in enumerate(skeleton.names + skeleton.end_names())}
    a = np.zeros(NUM_JOINTS, dtype=np.int64)
    b = np.zeros(NUM_JOINTS, dtype=np.int64)
    t = np.zeros(NUM_JOINTS)
    for j, name in enumerate(JOINT_NAMES):
        spec = table.joints[name]
        if isinstance(spec, str):
            a[j] = b[j] = index[spec]
        else:
            a[j], b[j], t[j] = index[spec[0]], index[spec[1]], float(spec[2])
    return a, b, t


def _swing(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(..., 3, 3) shortest-arc rotations taking directions u to v."""
    return quat_to_matrix(quat_between(u, v))


def _angle(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    c = np.sum(u * v, -1) / np.maximum(np.linalg.norm(u, axis=-1) * np.linalg.norm(v, axis=-1), 1e-12)
    return np.arccos(np.clip(c, -1.0, 1.0))


def _kabsch(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Rotations R (..., 3, 3) minimising sum_i |R src_i - dst_i|^2; src, dst (..., n, 3)."""
    h = np.einsum("...ni,...nj->...ij", dst, np.broadcast_to(src, dst.shape))
    u, _, vt = np.linalg.svd(h)
    flip = np.linalg.det(u @ vt) < 0  # no reflections
    u[flip, :, 2] *= -1
    return u @ vt


def _tpose_frames(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Canonical frames (K, 22, 3, 3) that pose the T-pose onto joint positions x (K, 22, 3)
    with the least swing per bone, and a T-pose-likeness score (K,) (mean swing, radians)."""
    k = x.shape[0]
    frames = np.empty((k, NUM_JOINTS, 3, 3))
    swing = np.zeros((k, NUM_JOINTS))
    for j in range(NUM_JOINTS):
        kids = list(CHILDREN[j])
        base = frames[:, PARENTS[j]] if j > 0 else np.broadcast_to(np.eye(3), (k, 3, 3))
        if len(kids) > 1:
            frames[:, j] = _kabsch(_DEFAULT_REST[kids] - _DEFAULT_REST[j], x[:, kids] - x[:, j:j + 1])
            if j > 0:  # spine3: how far its main bone (to the neck) is from the T-pose
                u = base @ (_DEFAULT_REST[kids[0]] - _DEFAULT_REST[j])
                swing[:, j] = _angle(u, x[:, kids[0]] - x[:, j])
        elif kids:
            u = base @ (_DEFAULT_REST[kids[0]] - _DEFAULT_REST[j])
            d = x[:, kids[0]] - x[:, j]
            frames[:, j] = _swing(u, d) @ base
            swing[:, j] = _angle(u, d)
        else:
            frames[:, j] = base
    score = swing.mean(1) + np.where(swing.max(1) > _DEGENERATE, 10.0, 0.0)
    return frames, score


def _choose_reference(src: np.ndarray, src_rot: np.ndarray, rest_src: np.ndarray,
                      reference: str | int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reference joint positions (22, 3), source rotations (22, 3, 3) and canonical frames."""
    eye = np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3))
    if reference == "rest":
        frames, _ = _tpose_frames(rest_src[None])
        return rest_src, eye, frames[0]
    if isinstance(reference, (int, np.integer)) and not isinstance(reference, bool):
        if not -src.shape[0] <= reference < src.shape[0]:
            raise FormatError(f"reference frame {reference} is outside the clip's "
                              f"{src.shape[0]} frames")
        frames, _ = _tpose_frames(src[reference][None])
        return src[reference], src_rot[reference], frames[0]
    if reference != "auto":
        raise FormatError(f"reference must be 'auto', 'rest' or a frame index, not {reference!r}")
    picks = np.unique(np.linspace(0, src.shape[0] - 1, min(src.shape[0], 64)).astype(np.int64))
    frames, score = _tpose_frames(np.concatenate([rest_src[None], src[picks]]))
    # The rest pose is preferred (same twist for every clip of a rig) unless it is far from a
    # T-pose; 0.35 rad of mean swing is an A-pose with bent elbows.
    if score[0] < 0.35 or score[0] <= score[1:].min():
        return rest_src, eye, frames[0]
    best = int(np.argmin(score[1:]))
    return src[picks[best]], src_rot[picks[best]], frames[best + 1]


def _rest_offsets(ref_x: np.ndarray, frames: np.ndarray, rig: str) -> np.ndarray:
    """(22, 3) canonical rest offsets: each bone of the reference pose seen from its parent's
    canonical frame (single-child bones come out along the T-pose direction)."""
    offsets = np.zeros((NUM_JOINTS, 3))
    for j in range(1, NUM_JOINTS):
        p = PARENTS[j]
        d = ref_x[j] - ref_x[p]
        if np.linalg.norm(d) < 1e-4:
            raise FormatError(f"rig {rig!r}: canonical bone {JOINT_NAMES[p]} -> {JOINT_NAMES[j]} "
                              f"has no length in the reference pose")
        offsets[j] = frames[p].T @ d
    return offsets


def _fit_branches(src: np.ndarray, offsets: np.ndarray, iterations: int = 3) -> np.ndarray:
    """Refit the rest offsets of the pelvis and spine3 children to the whole clip.

    A rigid canonical pelvis cannot follow rigs whose hips and spine hang from different
    rotating joints (CMU's LHipJoint/LowerBack); averaging each child's offset in the fitted
    frame (a few Kabsch / mean rounds) removes the constant part of that mismatch.
    """
    offsets = offsets.copy()
    for j in range(NUM_JOINTS):
        kids = list(CHILDREN[j])
        if len(kids) < 2:
            continue
        d = src[:, kids] - src[:, j:j + 1]  # (T, n, 3)
        for _ in range(iterations):
            r = _kabsch(offsets[kids], d)
            mean = np.einsum("tji,tnj->ni", r, d) / d.shape[0]  # mean of R^T d
            length = np.linalg.norm(d, axis=-1).mean(0)
            offsets[kids] = mean * (length / np.maximum(np.linalg.norm(mean, axis=-1), 1e-12))[:, None]
    return offsets


def _rest_from_offsets(offsets: np.ndarray) -> np.ndarray:
    """Offsets (22, 3), row 0 zero -> T-pose joints with the pelvis above the origin and the feet
    on the floor (the lowest joint at the height of default_rest_joints' foot joint, scaled)."""
    rest = joints_from_offsets(offsets)
    low = rest[:, 1].min()
    pelvis_above_low = -low
    ratio = _DEFAULT_REST[:, 1].min() / (_DEFAULT_REST[0, 1] - _DEFAULT_REST[:, 1].min())
    rest[:, 1] += -low + ratio * pelvis_above_low
    return rest


def _global_frames(src: np.ndarray, q0: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Canonical global rotations (T, 22, 3, 3): the source's (q0) swung onto the mapped bones."""
    q = np.empty_like(q0)
    for j in range(NUM_JOINTS):
        kids = list(CHILDREN[j])
        if len(kids) > 1:
            q[:, j] = _kabsch(offsets[kids], src[:, kids] - src[:, j:j + 1])
        elif kids:
            c = kids[0]
            u = q0[:, j] @ offsets[c]
            q[:, j] = _swing(u, src[:, c] - src[:, j]) @ q0[:, j]
        else:
            q[:, j] = q0[:, j]
    return q
