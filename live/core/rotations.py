"""Rotation math on numpy arrays, batch-agnostic.

Glossary: quaternions are (..., 4) arrays (w, x, y, z), unit norm, Hamilton product, active
rotations (``quat_rotate(q, v)`` rotates the vector v). Matrices are (..., 3, 3) and act on
column vectors (v' = R v). Euler angles follow BVH: an ``order`` string such as "ZXY" lists the
axes in the order their channels appear, and R = R_Z @ R_X @ R_Y (intrinsic rotations).
Every function takes any leading batch shape and is pure.
"""

from __future__ import annotations

import math

import numpy as np

_EPS = 1e-12


def skew(v: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) cross-product matrices: skew(a) @ b = a x b. Filled in place (a
    quarter of the time of stacking rows: the contact solve calls it every step)."""
    v = np.asarray(v, np.float64)
    out = np.zeros(v.shape[:-1] + (3, 3))
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    out[..., 0, 1], out[..., 0, 2] = -z, y
    out[..., 1, 0], out[..., 1, 2] = z, -x
    out[..., 2, 0], out[..., 2, 1] = -y, x
    return out


def quat_identity(shape: tuple[int, ...] = (), dtype=np.float64) -> np.ndarray:
    q = np.zeros(shape + (4,), dtype=dtype)
    q[..., 0] = 1.0
    return q


def quat_normalize(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    return q / np.maximum(n, _EPS)


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q)
    return np.concatenate([q[..., :1], -q[..., 1:]], axis=-1)


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b (apply b first, then a)."""
    a = np.asarray(a)
    b = np.asarray(b)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v (..., 3) by unit quaternions q (..., 4)."""
    q = np.asarray(q)
    v = np.asarray(v)
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def quat_canonical(q: np.ndarray) -> np.ndarray:
    """Pick the sign with w >= 0 so equal rotations compare equal."""
    q = np.asarray(q)
    return np.where(q[..., :1] < 0, -q, q)


def _quat_to_matrix_map() -> np.ndarray:
    """(16, 9): the rotation matrix (row-major) of a unit quaternion is linear in the products
    q_a q_b (flattened 4 x 4 outer product): R = I + (q q^T) C, one matmul instead of a dozen
    elementwise ops per entry on the small batches of a live frame."""
    c = np.zeros((4, 4, 9))
    w, x, y, z = range(4)
    for entry, terms in enumerate([
        [(y, y, -2), (z, z, -2)], [(x, y, 2), (w, z, -2)], [(x, z, 2), (w, y, 2)],
        [(x, y, 2), (w, z, 2)], [(x, x, -2), (z, z, -2)], [(y, z, 2), (w, x, -2)],
        [(x, z, 2), (w, y, -2)], [(y, z, 2), (w, x, 2)], [(x, x, -2), (y, y, -2)],
    ]):
        for a, b, k in terms:
            c[a, b, entry] += k
    return c.reshape(16, 9)


def _matrix_to_quat_map() -> tuple[np.ndarray, np.ndarray]:
    """(9, 16) and (16,): Shepperd's four candidate (unnormalised) quaternions, each 4 x 4 row
    one candidate, as one affine map of the flattened matrix; candidate i's pivot is entry (i, i)."""
    def m(r: int, c: int) -> int:  # row-major index of entry (r, c)
        return 3 * r + c

    rows = [  # candidate -> component -> [(matrix entry, sign)], plus the constant 1 on pivots
        [[(m(0, 0), 1), (m(1, 1), 1), (m(2, 2), 1)], [(m(2, 1), 1), (m(1, 2), -1)],
         [(m(0, 2), 1), (m(2, 0), -1)], [(m(1, 0), 1), (m(0, 1), -1)]],
        [[(m(2, 1), 1), (m(1, 2), -1)], [(m(0, 0), 1), (m(1, 1), -1), (m(2, 2), -1)],
         [(m(0, 1), 1), (m(1, 0), 1)], [(m(0, 2), 1), (m(2, 0), 1)]],
        [[(m(0, 2), 1), (m(2, 0), -1)], [(m(0, 1), 1), (m(1, 0), 1)],
         [(m(0, 0), -1), (m(1, 1), 1), (m(2, 2), -1)], [(m(1, 2), 1), (m(2, 1), 1)]],
        [[(m(1, 0), 1), (m(0, 1), -1)], [(m(0, 2), 1), (m(2, 0), 1)],
         [(m(1, 2), 1), (m(2, 1), 1)], [(m(0, 0), -1), (m(1, 1), -1), (m(2, 2), 1)]],
    ]
    k = np.zeros((9, 4, 4))
    for cand, comps in enumerate(rows):
        for comp, terms in enumerate(comps):
            for entry, sign in terms:
                k[entry, cand, comp] = sign
    return k.reshape(9, 16), np.eye(4).reshape(16)


_Q2M = _quat_to_matrix_map()
_I3_FLAT = np.eye(3).reshape(9)
_M2Q, _M2Q_ONE = _matrix_to_quat_map()


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    q = quat_normalize(q)
    outer = (q[..., :, None] * q[..., None, :]).reshape(q.shape[:-1] + (16,))
    return (outer @ _Q2M + _I3_FLAT).reshape(q.shape[:-1] + (3, 3))


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> unit quaternions with w >= 0 (Shepperd's method)."""
    m = np.asarray(m, dtype=np.float64)
    batch = m.shape[:-2]
    # Four candidate formulas; pick per row the one with the largest, best-conditioned pivot.
    cands = (m.reshape(-1, 9) @ _M2Q + _M2Q_ONE).reshape(-1, 4, 4)
    best = np.argmax(cands.reshape(-1, 16)[:, ::5], axis=1)  # the pivots: entries (i, i)
    q = cands[np.arange(len(cands)), best]
    q = quat_canonical(quat_normalize(q))
    return q.reshape(batch + (4,))


def quat_from_axis_angle(axis_angle: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) (axis * angle in radians) -> quaternions."""
    aa = np.asarray(axis_angle, dtype=np.float64)
    angle = np.linalg.norm(aa, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(half)/angle, with its limit 0.5 near zero.
    k = np.where(angle > 1e-8, np.sin(half) / np.maximum(angle, 1e-300), 0.5 - angle**2 / 48.0)
    return np.concatenate([np.cos(half), aa * k], axis=-1)


def quat_to_axis_angle(q: np.ndarray) -> np.ndarray:
    q = quat_canonical(quat_normalize(q))
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., :1])
    k = np.where(s > 1e-8, angle / np.maximum(s, 1e-300), 2.0)
    return v * k


def quat_angle(q: np.ndarray) -> np.ndarray:
    """Rotation angle in [0, pi] of each quaternion."""
    q = quat_normalize(q)
    return 2.0 * np.arccos(np.clip(np.abs(q[..., 0]), 0.0, 1.0))


def quat_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Shortest-arc rotation taking direction u to direction v (both (..., 3), any length)."""
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    u = u / np.maximum(np.linalg.norm(u, axis=-1, keepdims=True), _EPS)
    v = v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), _EPS)
    d = np.sum(u * v, axis=-1, keepdims=True)
    c = np.cross(u, v)
    q = np.concatenate([1.0 + d, c], axis=-1)
    # Opposite directions: rotate by pi about any axis orthogonal to u.
    opposite = (d[..., 0] < -1.0 + 1e-9)
    if np.any(opposite):
        ortho = np.cross(u, np.array([1.0, 0.0, 0.0]))
        small = np.linalg.norm(ortho, axis=-1) < 1e-6
        ortho = np.where(small[..., None], np.cross(u, np.array([0.0, 1.0, 0.0])), ortho)
        q = np.where(opposite[..., None], np.concatenate([np.zeros_like(d), ortho], axis=-1), q)
    return quat_normalize(q)


def quat_slerp(a: np.ndarray, b: np.ndarray, t: np.ndarray | float) -> np.ndarray:
    a = quat_normalize(a)
    b = quat_normalize(b)
    d = np.sum(a * b, axis=-1, keepdims=True)
    b = np.where(d < 0, -b, b)
    d = np.abs(d)
    t = np.asarray(t, dtype=np.float64)
    if t.ndim > 0 and t.shape[-1:] != (1,):
        t = t[..., None]
    theta = np.arccos(np.clip(d, -1.0, 1.0))
    s = np.sin(theta)
    lin = s < 1e-6
    wa = np.where(lin, 1.0 - t, np.sin((1.0 - t) * theta) / np.where(lin, 1.0, s))
    wb = np.where(lin, t, np.sin(t * theta) / np.where(lin, 1.0, s))
    return quat_normalize(wa * a + wb * b)


def axis_matrix(axis: str, angle: np.ndarray) -> np.ndarray:
    """Rotations about the coordinate axis "X", "Y" or "Z" by ``angle`` (...,) radians -> (..., 3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    one, zero = np.ones_like(angle), np.zeros_like(angle)
    if axis == "X":
        rows = [one, zero, zero, zero, c, -s, zero, s, c]
    elif axis == "Y":
        rows = [c, zero, s, zero, one, zero, -s, zero, c]
    elif axis == "Z":
        rows = [c, -s, zero, s, c, zero, zero, zero, one]
    else:
        raise ValueError(f"unknown rotation axis {axis!r}")
    return np.stack(rows, axis=-1).reshape(angle.shape + (3, 3))


def euler_to_matrix(angles: np.ndarray, order: str) -> np.ndarray:
    """Euler angles (..., 3) in radians, in ``order`` (e.g. "ZXY") -> matrices R = R_a R_b R_c."""
    angles = np.asarray(angles, dtype=np.float64)
    order = order.upper()
    m = axis_matrix(order[0], angles[..., 0])
    for i in (1, 2):
        m = m @ axis_matrix(order[i], angles[..., i])
    return m


def matrix_to_euler(m: np.ndarray, order: str) -> np.ndarray:
    """Inverse of ``euler_to_matrix`` for any of the six Tait-Bryan orders."""
    m = np.asarray(m, dtype=np.float64)
    order = order.upper()
    i, j, k = ("XYZ".index(a) for a in order)
    # sign of the permutation (i, j, k): +1 for cyclic orders.
    sign = 1.0 if (j - i) % 3 == 1 else -1.0
    mid = np.arcsin(np.clip(sign * m[..., i, k], -1.0, 1.0))
    first = np.arctan2(-sign * m[..., j, k], m[..., k, k])
    last = np.arctan2(-sign * m[..., i, j], m[..., i, i])
    # Gimbal lock: fold everything into the first angle.
    locked = np.abs(np.abs(sign * m[..., i, k]) - 1.0) < 1e-9
    if np.any(locked):
        first_locked = np.arctan2(sign * m[..., k, j], m[..., j, j])
        first = np.where(locked, first_locked, first)
        last = np.where(locked, 0.0, last)
    return np.stack([first, mid, last], axis=-1)


def matrix_to_6d(m: np.ndarray) -> np.ndarray:
    """(..., 3, 3) -> (..., 6): the first two columns (Zhou et al.'s continuous representation)."""
    m = np.asarray(m)
    return np.concatenate([m[..., :, 0], m[..., :, 1]], axis=-1)


def sixd_to_matrix(d6: np.ndarray) -> np.ndarray:
    """(..., 6) -> (..., 3, 3) by Gram-Schmidt."""
    d6 = np.asarray(d6, dtype=np.float64)
    a, b = d6[..., :3], d6[..., 3:]
    x = a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), _EPS)
    b = b - np.sum(x * b, axis=-1, keepdims=True) * x
    y = b / np.maximum(np.linalg.norm(b, axis=-1, keepdims=True), _EPS)
    z = np.cross(x, y)
    return np.stack([x, y, z], axis=-1)


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle in degrees between two non-zero 3-vectors (directions, not rotations)."""
    c = float(a @ b) / math.sqrt(float(a @ a) * float(b @ b))
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))
