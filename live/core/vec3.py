"""Plain-float 3-vectors, 3x3 matrices and quaternions for per-frame hot paths.

One frame of the analytic retargeter is a few dozen rotations of single joints, one IMU sample
one quaternion. On arrays that small numpy pays ~1-5 us of call overhead per operation, plain
Python floats ~0.1 us, so the per-frame solver (live/retarget/analytic.py), the two-bone IK
(live/retarget/ik.py) and the IMU decoders (drivers/) run on these and make arrays once per frame.
Vectors are 3-sequences of floats, matrices 3 rows acting on column vectors (v' = M v),
quaternions 4-sequences (w, x, y, z) with the Hamilton product, as in live/core/rotations.py (its
batched numpy counterpart). Pure functions; float64 throughout, so results equal numpy's to
rounding.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

Vec = Sequence[float]
Mat = Sequence[Vec]
Quat = Sequence[float]
EPS = 1e-12
IDENTITY: tuple[tuple[float, float, float], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


def add(a: Vec, b: Vec) -> tuple[float, float, float]:
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def sub(a: Vec, b: Vec) -> tuple[float, float, float]:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def scale(a: Vec, s: float) -> tuple[float, float, float]:
    return (a[0] * s, a[1] * s, a[2] * s)


def dot(a: Vec, b: Vec) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a: Vec, b: Vec) -> tuple[float, float, float]:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def norm(a: Vec) -> float:
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


def unit(a: Vec) -> tuple[float, float, float]:
    """a / |a| (a zero vector stays zero, as live.retarget.ik.normalize does on arrays)."""
    n = max(norm(a), EPS)
    return (a[0] / n, a[1] / n, a[2] / n)


def clamp(x: float, lo: float = -1.0, hi: float = 1.0) -> float:
    return lo if x < lo else hi if x > hi else x


def mv(m: Mat, v: Vec) -> tuple[float, float, float]:
    """M v."""
    return (dot(m[0], v), dot(m[1], v), dot(m[2], v))


def mtv(m: Mat, v: Vec) -> tuple[float, float, float]:
    """M^T v."""
    return (m[0][0] * v[0] + m[1][0] * v[1] + m[2][0] * v[2],
            m[0][1] * v[0] + m[1][1] * v[1] + m[2][1] * v[2],
            m[0][2] * v[0] + m[1][2] * v[1] + m[2][2] * v[2])


def mtm(a: Mat, b: Mat) -> tuple[tuple[float, float, float], ...]:
    """A^T B."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = a
    return mm(((a00, a10, a20), (a01, a11, a21), (a02, a12, a22)), b)


def mm(a: Mat, b: Mat) -> tuple[tuple[float, float, float], ...]:
    """A B (rows unrolled: these run thousands of times a frame, and a generator costs more than
    the arithmetic)."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = a
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = b
    return ((a00 * b00 + a01 * b10 + a02 * b20, a00 * b01 + a01 * b11 + a02 * b21, a00 * b02 + a01 * b12 + a02 * b22),
            (a10 * b00 + a11 * b10 + a12 * b20, a10 * b01 + a11 * b11 + a12 * b21, a10 * b02 + a11 * b12 + a12 * b22),
            (a20 * b00 + a21 * b10 + a22 * b20, a20 * b01 + a21 * b11 + a22 * b21, a20 * b02 + a21 * b12 + a22 * b22))


def columns(e1: Vec, e2: Vec, e3: Vec) -> tuple[tuple[float, float, float], ...]:
    """The matrix with columns e1, e2, e3."""
    return ((e1[0], e2[0], e3[0]), (e1[1], e2[1], e3[1]), (e1[2], e2[2], e3[2]))


def axis_angle(k: Vec, angle: float) -> tuple[tuple[float, float, float], ...]:
    """Rotation about the unit axis k by angle (radians): c I + s [k]x + (1 - c) k k^T."""
    c, s = math.cos(angle), math.sin(angle)
    t = 1.0 - c
    x, y, z = k
    return ((c + t * x * x, t * x * y - s * z, t * x * z + s * y),
            (t * y * x + s * z, c + t * y * y, t * y * z - s * x),
            (t * z * x - s * y, t * z * y + s * x, c + t * z * z))


def between_units(u: Vec, v: Vec) -> tuple[tuple[float, float, float], ...]:
    """Shortest-arc rotation taking the unit vector u to the direction of v (any length), the
    rotation of ``live.core.rotations.quat_between``; opposite directions turn by pi about an axis
    orthogonal to u. Rodrigues with sin = |c|, cos = d: R = d I + [c]x + c c^T / (1 + d)."""
    v = unit(v)
    c = cross(u, v)
    d = dot(u, v)
    if d < -1.0 + 1e-9:
        o = cross(u, (1.0, 0.0, 0.0))
        if norm(o) < 1e-6:
            o = cross(u, (0.0, 1.0, 0.0))
        x, y, z = unit(o)
        return ((2.0 * x * x - 1.0, 2.0 * x * y, 2.0 * x * z),
                (2.0 * y * x, 2.0 * y * y - 1.0, 2.0 * y * z),
                (2.0 * z * x, 2.0 * z * y, 2.0 * z * z - 1.0))
    s = 1.0 / (1.0 + d)
    return ((d + c[0] * c[0] * s, -c[2] + c[0] * c[1] * s, c[1] + c[0] * c[2] * s),
            (c[2] + c[1] * c[0] * s, d + c[1] * c[1] * s, -c[0] + c[1] * c[2] * s),
            (-c[1] + c[2] * c[0] * s, c[0] + c[2] * c[1] * s, d + c[2] * c[2] * s))


def frame(a: Vec, b: Vec) -> tuple[tuple[float, float, float], ...]:
    """Orthonormal frame with columns (a, b orthogonalised against a, their cross product)."""
    e1 = unit(a)
    e3 = unit(cross(e1, b))
    return columns(e1, cross(e3, e1), e3)


def wrap_angle(a: float) -> float:
    """An angle (radians) wrapped into [-pi, pi) (live.core.heading.wrap_angle on one float)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


# ----------------------------------------------------------------------------- quaternions


def quat_mul(a: Quat, b: Quat) -> tuple[float, float, float, float]:
    """Hamilton product a * b (apply b first, then a)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def quat_conj(q: Quat) -> tuple[float, float, float, float]:
    """The conjugate (the inverse of a unit quaternion)."""
    return (q[0], -q[1], -q[2], -q[3])


def quat_norm(q: Quat) -> float:
    return math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])


def quat_from_matrix(m: Mat) -> tuple[float, float, float, float]:
    """Rotation matrix (3 rows) -> quaternion, Shepperd's method (pivot on the trace first)."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = m
    tr = m00 + m11 + m22
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        return (0.25 * s, (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s)
    if m00 > m11 and m00 > m22:
        s = math.sqrt(1.0 + m00 - m11 - m22) * 2
        return ((m21 - m12) / s, 0.25 * s, (m01 + m10) / s, (m02 + m20) / s)
    if m11 > m22:
        s = math.sqrt(1.0 + m11 - m00 - m22) * 2
        return ((m02 - m20) / s, (m01 + m10) / s, 0.25 * s, (m12 + m21) / s)
    s = math.sqrt(1.0 + m22 - m00 - m11) * 2
    return ((m10 - m01) / s, (m02 + m20) / s, (m12 + m21) / s, 0.25 * s)
