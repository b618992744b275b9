"""Kalman filters on rotations for depth + IMU fusion: what the suit gets wrong, learnt from depth.

A suit's segment rotation (after calibration, ``live.imu.calibration``) is wrong in two slow
ways: the heading of its world (a yaw about world up: where the performer faced during the hold,
then each sensor's own heading drift, magnetometer disturbances) and its mounting (the sensor
slid in its pocket, or the calibration pose was not exactly the canonical one: a rotation in the
segment's frame). The depth skeleton sees each bone's direction with white-ish noise. So:

- ``HeadingFilter``: one scalar Kalman filter on the yaw shared by all sensors (the calibration
  frame's heading in the world, plus the drift they share), measured every frame as the yaw that
  best turns the suit's bones onto the depth bones (``live.core.heading.yaw_between``), with a
  variance from how much horizontal bone the depth skeleton showed. It starts from the first
  measurement, and again from the majority if the next few outvote it (``majority_angle``).
- ``SensorFilter``: one error-state Kalman filter per sensor on (phi, delta): phi (3,) a rotation
  in the segment frame (mounting error) and delta a yaw in the world (this sensor's own drift).
  Each frame its segment's child bones as the depth skeleton sees them are the measurement; a
  measurement that disagrees beyond ``gate`` standard deviations (a limb the regressor lost but
  still reports) is refused. The state covariance says how well the suit's bone directions are
  known, which is what the fusion weighs against the depth's confidence.

Pure numpy; angles in radians, directions unit vectors in the world (+y up).
"""

from __future__ import annotations

import numpy as np

from live.core.heading import mean_angle, wrap_angle, yaw_quat
from live.core.rotations import quat_from_axis_angle, quat_multiply, quat_normalize, quat_rotate, quat_to_matrix, skew

UP = np.array([0.0, 1.0, 0.0])


class HeadingFilter:
    """Scalar Kalman filter on the shared heading (radians). ``variance`` is None until the first
    measurement: the first one is taken as it is (any angle), later ones are innovations of
    ``update`` gated at ``gate`` standard deviations."""

    def __init__(self, *, drift_rate: float = np.radians(0.5), initial_std: float = np.radians(20.0),
                 gate: float = 4.0):
        self.yaw = 0.0
        self.variance: float | None = None
        self.q = drift_rate ** 2
        self.initial_var = initial_std ** 2
        self.gate = gate
        self.refused = 0

    def predict(self, dt: float) -> None:
        if self.variance is not None:
            self.variance += self.q * dt

    def update(self, innovation: float, measurement_var: float) -> None:
        """innovation: the measured yaw minus the current estimate (radians, wrapped)."""
        innovation = float(wrap_angle(innovation))
        if self.variance is None:
            self.yaw = float(wrap_angle(self.yaw + innovation))
            self.variance = max(self.initial_var, measurement_var)
            return
        s = self.variance + measurement_var
        if innovation * innovation > self.gate ** 2 * s:
            self.refused += 1
            return
        k = self.variance / s
        self.yaw = float(wrap_angle(self.yaw + k * innovation))
        self.variance = (1.0 - k) * self.variance


def majority_angle(votes: list[float], tolerance: float) -> float:
    """The circular mean of the largest group of angles (radians) within ``tolerance`` of one of
    them (ties: the earliest one's group): what most of a filter's first measurements say, so that
    one odd frame (a depth skeleton mirrored left-right while the regressor settles) is outvoted."""
    a = np.asarray(votes, np.float64)
    close = np.abs(wrap_angle(a[:, None] - a[None, :])) <= tolerance
    group = a[close[int(np.argmax(close.sum(axis=1)))]]
    return mean_angle(group)


class SensorFilter:
    """Error-state Kalman filters of S sensors at once: each sensor's correction is a segment-frame
    rotation ``mount`` (S, 4) and a world yaw ``drift`` (S,), with covariance ``P`` (S, 4, 4) over
    (phi_x, phi_y, phi_z, delta). A segment rotation G (from the suit, heading applied) is
    corrected as yaw(drift) * G * mount.

    mount_std: prior std of the mounting error per axis; mount_rate / drift_rate: how fast each may
    change (random walks, rad/sqrt(s)); gate: Mahalanobis distance beyond which a bone
    measurement is refused; mount_free (S,) bool: sensors whose mounting is learnt (default all;
    the others keep theirs and learn only their drift)."""

    def __init__(self, sensors: int, *, mount_free: np.ndarray | None = None, mount_std: float = np.radians(8.0), drift_std: float = np.radians(3.0),
                 mount_rate: float = np.radians(0.3), drift_rate: float = np.radians(0.3), gate: float = 3.5):
        self.S = int(sensors)
        self.mount = np.zeros((self.S, 4))
        self.mount[:, 0] = 1.0
        self.drift = np.zeros(self.S)
        self.P = np.zeros((self.S, 4, 4))
        self.P[:, :3, :3] = np.eye(3) * mount_std ** 2
        self.P[:, 3, 3] = drift_std ** 2
        free = np.ones(self.S, bool) if mount_free is None else np.asarray(mount_free, bool)
        self.P[~free, :3, :3] = 0.0
        self.Q = np.zeros((self.S, 4, 4))
        self.Q[:, 3, 3] = drift_rate ** 2
        self.Q[free, :3, :3] = np.eye(3) * mount_rate ** 2
        self.gate = gate
        self.accepted = np.zeros(self.S, np.int64)
        self.refused = np.zeros(self.S, np.int64)

    def predict(self, dt: float) -> None:
        self.P += self.Q * dt

    def correct(self, seg: np.ndarray) -> np.ndarray:
        """Segment rotations (S, 4) -> corrected (S, 4)."""
        return quat_normalize(quat_multiply(quat_multiply(yaw_quat(self.drift), seg), self.mount))

    def jacobian(self, seg: np.ndarray, rows: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """K bones at once: the predicted unit directions (K, 3) of bones with rest offsets (K, 3)
        in the frames of the segments of sensors ``rows`` (K,) (uncorrected segment rotations seg
        (S, 4)), and their Jacobians (K, 3, 4) with respect to each sensor's error state."""
        o = offsets / np.maximum(np.linalg.norm(offsets, axis=-1, keepdims=True), 1e-9)
        world = quat_multiply(yaw_quat(self.drift[rows]), seg[rows])
        rot = quat_to_matrix(quat_multiply(world, self.mount[rows]))
        u = np.einsum("kij,kj->ki", rot, o)
        H = np.empty((len(o), 3, 4))
        H[:, :, :3] = -rot @ skew(o)          # d(R exp(phi) o)/d phi = -R [o]x
        H[:, :, 3] = np.cross(UP, u)          # d(yaw(delta) u)/d delta = up x u
        return u, H

    def direction_var(self, H: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """(K,) variance (rad^2, per axis across the bone) of predicted directions with Jacobians
        H (K, 3, 4) of sensors ``rows``."""
        cov = H @ self.P[rows] @ H.transpose(0, 2, 1)
        return np.trace(cov, axis1=1, axis2=2) / 2.0

    def update(self, H: np.ndarray, u: np.ndarray, rows: np.ndarray, observed: np.ndarray, variance: np.ndarray,
               slots: np.ndarray) -> np.ndarray:
        """Depth bone directions observed (K, 3) (any length) of the K bones predicted as u (K, 3)
        with Jacobians H (K, 3, 4), of sensors ``rows`` (K,), each with an isotropic variance (K,)
        rad^2; ``slots`` (K,) numbers each sensor's bones 0, 1, 2 (one sensor's bones are taken in
        turn, all sensors at once). A bone whose innovation is beyond the gate is refused; returns
        the (K,) accepted mask."""
        z = observed / np.maximum(np.linalg.norm(observed, axis=-1, keepdims=True), 1e-9)
        dx = np.zeros((self.S, 4))
        ok = np.zeros(len(u), bool)
        eye3, eye4 = np.eye(3), np.eye(4)
        for slot in range(int(slots.max()) + 1 if len(slots) else 0):
            k = np.flatnonzero(slots == slot)
            r = rows[k]
            P = self.P[r]
            Hk = H[k]
            y = (z[k] - u[k]) - np.einsum("kij,kj->ki", Hk, dx[r])
            S = Hk @ P @ Hk.transpose(0, 2, 1) + variance[k, None, None] * eye3
            d2 = np.einsum("ki,ki->k", y, np.linalg.solve(S, y[..., None])[..., 0])
            good = d2 <= self.gate ** 2
            ok[k] = good
            if not good.any():
                continue
            k, r, P, Hk, y, S = k[good], r[good], P[good], Hk[good], y[good], S[good]
            K = np.linalg.solve(S, Hk @ P).transpose(0, 2, 1)  # P H^T S^-1 (S, P symmetric)
            dx[r] += np.einsum("kij,kj->ki", K, y)
            P = (eye4 - K @ Hk) @ P
            self.P[r] = 0.5 * (P + P.transpose(0, 2, 1))
        self.refused += np.bincount(rows[~ok], minlength=self.S)
        self.accepted += np.bincount(rows[ok], minlength=self.S)
        changed = np.any(dx != 0.0, axis=1)
        if changed.any():
            self.mount[changed] = quat_normalize(quat_multiply(self.mount[changed], quat_from_axis_angle(dx[changed, :3])))
            self.drift = wrap_angle(self.drift + dx[:, 3])
        return ok


def rotate_offsets(rot: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Offsets (K, 3) turned by one rotation (4,) -> (K, 3)."""
    return quat_rotate(np.broadcast_to(rot, offsets.shape[:-1] + (4,)), offsets)


__all__ = ["HeadingFilter", "SensorFilter", "majority_angle", "skew", "rotate_offsets"]
