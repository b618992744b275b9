"""Two-bone limb IK and the small rotation-matrix helpers the retargeter runs on.

Matrices are (..., 3, 3) acting on column vectors (v' = R v), like live/rotations.py. The
retargeter works on matrices rather than quaternions on its hot path because a batched matmul is
one numpy call where a quaternion product is a dozen; results are converted to quaternions once.
All functions are pure and take any leading batch shape.
"""

from __future__ import annotations

import numpy as np

_EPS = 1e-12
# Levi-Civita symbol: one einsum against it replaces np.cross / a stacked skew matrix, which
# cost 5-10 times more on the few-element arrays of a single frame.
_LC = np.zeros((3, 3, 3))
_LC[0, 1, 2] = _LC[1, 2, 0] = _LC[2, 0, 1] = 1.0
_LC[0, 2, 1] = _LC[2, 1, 0] = _LC[1, 0, 2] = -1.0
_I3 = np.eye(3)


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products of (..., 3) arrays -> (...)."""
    return np.einsum("...i,...i->...", a, b)


def normalize(v: np.ndarray) -> np.ndarray:
    """(..., 3) -> unit vectors (zero vectors stay zero)."""
    return v / np.maximum(np.sqrt(dot(v, v)), _EPS)[..., None]


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products of (..., 3) arrays (broadcasting)."""
    return np.einsum("ijk,...j,...k->...i", _LC, a, b)


def skew(v: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) cross-product matrices [v]x (skew(v) @ u == cross(v, u))."""
    return np.einsum("ijk,...k->...ij", -_LC, v)


def axis_angle_matrix(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Unit axes (..., 3) and angles (...) in radians -> rotation matrices (..., 3, 3) (Rodrigues)."""
    a = np.asarray(angle)[..., None, None]
    c = np.cos(a)
    return c * _I3 + np.sin(a) * skew(axis) + (1.0 - c) * (axis[..., :, None] * axis[..., None, :])


def rotation_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Shortest-arc rotation matrices (..., 3, 3) taking direction u to direction v (any lengths).

    Same rotation as ``live.rotations.quat_between``; opposite directions turn by pi about an axis
    orthogonal to u.
    """
    return rotation_between_units(normalize(np.asarray(u, dtype=np.float64)), np.asarray(v, dtype=np.float64))


def rotation_between_units(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``rotation_between`` for u already normalised (e.g. rest directions normalised once)."""
    v = normalize(v)
    c = cross(u, v)
    d = dot(u, v)
    opposite = d < -1.0 + 1e-9
    # Rodrigues with sin = |c|, cos = d: R = d I + [c]x + c c^T / (1 + d).
    scale = 1.0 / np.where(opposite, 1.0, 1.0 + d)
    r = d[..., None, None] * _I3 + skew(c) + (c[..., :, None] * c[..., None, :]) * scale[..., None, None]
    if opposite.any():
        ortho = cross(u, np.array([1.0, 0.0, 0.0]))
        small = np.linalg.norm(ortho, axis=-1) < 1e-6
        ortho = normalize(np.where(small[..., None], cross(u, np.array([0.0, 1.0, 0.0])), ortho))
        flip = 2.0 * ortho[..., :, None] * ortho[..., None, :] - np.eye(3)
        r = np.where(opposite[..., None, None], flip, r)
    return r


def two_bone_ik(
    a: np.ndarray,
    b: np.ndarray,
    c: np.ndarray,
    target: np.ndarray,
    bend_hint: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """World-space corrections that bring the end c of the chain a-b-c to ``target``.

    a, b, c: (..., 3) root, middle and end joint positions (hip, knee, ankle); target (..., 3);
    bend_hint (..., 3): the rotation axis along which the middle joint flexes, used when the limb
    is straight and its own plane is undefined (for a knee, the thigh's world x axis).
    Returns (delta_upper, delta_lower), each (..., 3, 3): the new global rotation of the upper
    bone is ``delta_upper @ G_a`` and of the lower bone ``delta_lower @ G_b``. Bone lengths are
    kept; an unreachable target leaves the limb pointing at it, fully stretched (minus 1e-4 of
    its length, so that the knee keeps a defined plane) or fully folded.
    """
    ab = b - a
    cb = c - b
    ac = c - a
    l_ab = np.sqrt(dot(ab, ab))
    l_cb = np.sqrt(dot(cb, cb))
    l_ac = np.sqrt(dot(ac, ac))
    l_at = np.sqrt(dot(target - a, target - a))
    reach = l_ab + l_cb
    l_at = np.minimum(np.maximum(l_at, np.abs(l_ab - l_cb) + 1e-4 * reach), reach * (1.0 - 1e-4))
    # Interior angles now (from the known lengths) and wanted (law of cosines), at the root and
    # at the middle joint, stacked (2, ...): one arccos for all four; the bend plane's normal
    # rotates both.
    cos_now = np.stack([dot(ac, ab) / np.maximum(l_ac * l_ab, _EPS), -dot(ab, cb) / np.maximum(l_ab * l_cb, _EPS)])
    cos_want = np.stack([(l_cb**2 - l_ab**2 - l_at**2) / (-2.0 * l_ab * l_at),
                         (l_at**2 - l_ab**2 - l_cb**2) / (-2.0 * l_ab * l_cb)])
    turn = np.arccos(np.minimum(np.maximum(np.stack([cos_want, cos_now]), -1.0), 1.0))
    plane = cross(ac, ab)
    plane_n = np.sqrt(dot(plane, plane))
    # A straight limb has no plane: bend about the hinge hint (its sign chosen to match
    # cross(ac, ab) of a naturally flexed limb).
    straight = plane_n < 1e-6 * np.maximum(l_ab * (l_ab + l_cb), _EPS)
    hint = np.asarray(bend_hint, dtype=np.float64)
    hint = hint - dot(hint, ab)[..., None] * ab / np.maximum(l_ab**2, _EPS)[..., None]
    axis0 = np.where(straight[..., None], -normalize(hint), plane / np.maximum(plane_n, _EPS)[..., None])
    r0, r1 = axis_angle_matrix(axis0, turn[0] - turn[1])
    # The two bends keep the end on the old a-c line (up to rounding); swing it onto the target.
    end = ab + np.einsum("...ij,...j->...i", r1, cb)
    r2 = rotation_between(np.einsum("...ij,...j->...i", r0, end), target - a)
    upper = r2 @ r0
    return upper, upper @ r1


def apply_limb_ik(
    glob: np.ndarray,
    loc: np.ndarray,
    pos: np.ndarray,
    offsets: np.ndarray,
    limbs: np.ndarray,
    hinges: np.ndarray,
    targets: np.ndarray,
    children: tuple[tuple[int, ...], ...],
    parents: np.ndarray,
) -> None:
    """Pose limbs of one frame so their end joints reach targets, in place.

    glob, loc (22, 3, 3) global and local rotations; pos (22, 3) joints; offsets (22, 3) rest
    offsets; limbs (K, 3) joint indices (root, middle, end); hinges (K, 3) rest hinge axes of the
    middle joints; targets (K, 3). The end joints keep their world orientation (a locked foot
    keeps its angle to the floor) and their descendants move rigidly with them.
    """
    r, m, e = limbs[:, 0], limbs[:, 1], limbs[:, 2]
    hint = np.einsum("kij,kj->ki", glob[r], hinges)
    upper, lower = two_bone_ik(pos[r], pos[m], pos[e], targets, hint)
    g_r = upper @ glob[r]
    g_m = lower @ glob[m]
    old_e = pos[e].copy()
    pos[m] = pos[r] + np.einsum("kij,kj->ki", g_r, offsets[m])
    pos[e] = pos[m] + np.einsum("kij,kj->ki", g_m, offsets[e])
    glob[r], glob[m] = g_r, g_m
    loc[r] = np.swapaxes(glob[parents[r]], -1, -2) @ g_r
    loc[m] = np.swapaxes(g_r, -1, -2) @ g_m
    loc[e] = np.swapaxes(g_m, -1, -2) @ glob[e]
    for k, end in enumerate(e):
        stack = list(children[end])
        while stack:
            c = stack.pop()
            pos[c] += pos[end] - old_e[k]
            stack.extend(children[c])
