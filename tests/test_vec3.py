"""The plain-float 3-vector / 3x3 helpers of the per-frame retargeter agree with live.core.rotations."""

from __future__ import annotations

import numpy as np
import pytest

from live.core import vec3 as v3
from live.core.rotations import quat_between, quat_from_axis_angle, quat_to_matrix

RNG = np.random.default_rng(7)


@pytest.mark.parametrize("case", range(20))
def test_between_units_is_the_shortest_arc(case):
    u, v = RNG.normal(size=(2, 3))
    if case == 0:
        v = -u * 2.5  # opposite directions: a half turn about an axis orthogonal to u
    if case == 1:
        u, v = np.array([1.0, 0, 0]), np.array([-1.0, 0, 0])  # opposite along x: the y fallback
    u = u / np.linalg.norm(u)
    r = np.array(v3.between_units(u.tolist(), v.tolist()))
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    np.testing.assert_allclose(r @ u, v / np.linalg.norm(v), atol=1e-12)
    if case > 1:
        np.testing.assert_allclose(r, quat_to_matrix(quat_between(u, v)), atol=1e-12)


def test_axis_angle_frame_and_products():
    for _ in range(10):
        axis = RNG.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = RNG.uniform(-np.pi, np.pi)
        want = quat_to_matrix(quat_from_axis_angle(axis * angle))
        np.testing.assert_allclose(np.array(v3.axis_angle(axis.tolist(), angle)), want, atol=1e-12)
        a, b = RNG.normal(size=(2, 3, 3))
        x = RNG.normal(size=3)
        np.testing.assert_allclose(np.array(v3.mm(a.tolist(), b.tolist())), a @ b, atol=1e-12)
        np.testing.assert_allclose(np.array(v3.mtm(a.tolist(), b.tolist())), a.T @ b, atol=1e-12)
        np.testing.assert_allclose(np.array(v3.mtv(a.tolist(), x.tolist())), a.T @ x, atol=1e-12)
        f = np.array(v3.frame(x.tolist(), b[0].tolist()))
        np.testing.assert_allclose(f.T @ f, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(f[:, 0], x / np.linalg.norm(x), atol=1e-12)
        assert np.dot(np.cross(f[:, 0], b[0]), f[:, 2]) > 0  # e3 along a x b
    assert v3.unit((0.0, 0.0, 0.0)) == (0.0, 0.0, 0.0)
