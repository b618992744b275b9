"""Heading: yaw about world +y (up), of rotations and of directions, batch-agnostic numpy.

A yaw by +a turns +z toward +x: (x, z) -> (x cos a + z sin a, -x sin a + z cos a), so the heading
of a horizontal direction (x, z) is atan2(x, z) (0 = facing +z, the canonical T-pose's facing).
Quaternions are (w, x, y, z), matrices act on column vectors, as in live/core/rotations.py; the
one-float angle wrap of the per-frame solver is live.core.vec3.wrap_angle.
"""

from __future__ import annotations

import numpy as np

from live.core.rotations import axis_matrix
from live.core.skeleton import JOINT_INDEX as _J


def yaw_quat(angle: np.ndarray | float) -> np.ndarray:
    """Rotations about world +y by ``angle`` (...,) radians -> (..., 4)."""
    a = 0.5 * np.asarray(angle, dtype=np.float64)
    z = np.zeros_like(a)
    return np.stack([np.cos(a), z, np.sin(a), z], axis=-1)


def yaw_matrix(angle: np.ndarray | float) -> np.ndarray:
    """Rotations about world +y by ``angle`` (...,) radians -> (..., 3, 3)."""
    return axis_matrix("Y", np.asarray(angle, dtype=np.float64))


def yaw_of(q: np.ndarray) -> np.ndarray:
    """Heading (...,) radians of rotations (..., 4): the angle of their twist about world +y."""
    q = np.asarray(q, dtype=np.float64)
    return 2.0 * np.arctan2(q[..., 2], q[..., 0])


def direction_yaw(d: np.ndarray) -> np.ndarray:
    """Heading (...,) radians of directions (..., 3): the yaw taking +z to their horizontal part."""
    d = np.asarray(d)
    return np.arctan2(d[..., 0], d[..., 2])


def body_heading(joints: np.ndarray) -> np.ndarray:
    """Heading (...,) radians of the way 22-joint bodies (..., 22, 3) face: square to the direction
    across hips and shoulders (left minus right), so 0 for a body facing +z."""
    j = np.asarray(joints)
    a = j[..., _J["left_hip"], :] - j[..., _J["right_hip"], :] + j[..., _J["left_shoulder"], :] \
        - j[..., _J["right_shoulder"], :]
    return np.arctan2(-a[..., 2], a[..., 0])


def wrap_angle(a: np.ndarray | float) -> np.ndarray:
    """Angles (radians) wrapped into [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def mean_angle(a: np.ndarray) -> float:
    """Circular mean (radians) of angles ``a`` (any shape): the heading of the mean of their unit
    vectors, so that -179 and +179 degrees average to 180, not 0."""
    a = np.asarray(a, np.float64)
    return float(np.arctan2(np.sin(a).mean(), np.cos(a).mean()))


def yaw_between(pred: np.ndarray, obs: np.ndarray, weight: np.ndarray) -> tuple[float, float]:
    """Yaw (radians) that best turns directions pred (K, 3) onto obs (K, 3), with weights (K,);
    returns (angle, evidence), evidence = weighted horizontal length product."""
    p = pred[:, [0, 2]]
    o = obs[:, [0, 2]]
    s = np.sum(weight * (p[:, 1] * o[:, 0] - p[:, 0] * o[:, 1]))
    c = np.sum(weight * (p[:, 0] * o[:, 0] + p[:, 1] * o[:, 1]))
    return float(np.arctan2(s, c)), float(np.hypot(s, c))
