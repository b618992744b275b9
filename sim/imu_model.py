"""What the IMUs of a suit would measure on a body performing a motion (pure numpy).

A sensor strapped to a segment turns with the global rotation of the segment's joint (see
drivers/layouts) times a fixed mounting rotation. From a motion (local rotations (T, 22, 4),
root (T, 3), rest joints (22, 3), fps) this module computes per-sensor orientations
(sensor-to-world, livecap world: +Y up), body-frame rate of turn, specific force and magnetic
field, with optional sensor noise and a slow heading drift like a real fusion filter's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from live.core.kinematics import forward_kinematics
from live.core.rotations import (
    quat_conjugate,
    quat_from_axis_angle,
    quat_multiply,
    quat_normalize,
    quat_rotate,
    quat_to_axis_angle,
)
from live.core.skeleton import NUM_JOINTS, default_rest_joints
from live.core.timing import frame_interval_s

GRAVITY = 9.81
#: Earth field in the livecap world (x East, y Up, z South): 60 deg inclination, unit norm (a.u.).
MAG_WORLD = np.array([0.0, -np.sin(np.radians(60.0)), -np.cos(np.radians(60.0))])


@dataclass(frozen=True)
class ImuNoise:
    """Sensor imperfections. Stds are per sample; yaw_drift_std is the std of each sensor's
    constant heading drift rate (rad/s) about world +Y; gyro_bias_std the std of its gyro bias."""

    gyro_std: float = 0.0
    gyro_bias_std: float = 0.0
    acc_std: float = 0.0
    mag_std: float = 0.0
    orient_std: float = 0.0
    yaw_drift_std: float = 0.0


@dataclass(frozen=True)
class ImuTrack:
    """Per-sensor IMU signals of one motion. T frames at ``fps``, S sensors.

    sensors (S,) int64 ids; joints (S,) joint index per sensor; mounting (S, 4) sensor-in-segment
    rotations; quats (T, S, 4) reported sensor-to-world orientations (with drift and noise);
    true_quats (T, S, 4) without them; gyro (T, S, 3) rad/s, acc (T, S, 3) m/s^2 specific force,
    mag (T, S, 3) a.u., all in the sensor frame.
    """

    fps: float
    sensors: np.ndarray
    joints: np.ndarray
    mounting: np.ndarray
    quats: np.ndarray
    true_quats: np.ndarray
    gyro: np.ndarray
    acc: np.ndarray
    mag: np.ndarray

    @property
    def frames(self) -> int:
        return self.quats.shape[0]


@dataclass(frozen=True)
class SimpleMotion:
    """The fields of live.motion.clips.Motion that the IMU simulation needs."""

    fps: float
    rotations: np.ndarray
    root: np.ndarray
    rest_joints: np.ndarray
    name: str = "random"


def random_rotations(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 4) uniformly distributed unit quaternions with w >= 0."""
    q = quat_normalize(rng.normal(size=(n, 4)))
    return q * np.where(q[:, :1] < 0, -1.0, 1.0)


def random_mounting(n: int, seed: int | None) -> np.ndarray:
    """(n, 4) fixed sensor-to-segment rotations: uniform random when seeded, identity for None."""
    if seed is None:
        q = np.zeros((n, 4))
        q[:, 0] = 1.0
        return q
    return random_rotations(n, np.random.default_rng(seed))


def random_smooth_motion(frames: int, fps: float = 60.0, seed: int = 0, amplitude: float = 0.5
                         ) -> SimpleMotion:
    """A smooth random motion: every joint's local rotation vector is a sum of three sinusoids
    (0.1-1.5 Hz, up to ``amplitude`` rad), the root wanders slowly. For tests and demos."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames) / fps
    freq = rng.uniform(0.1, 1.5, size=(3, NUM_JOINTS, 3))
    phase = rng.uniform(0, 2 * np.pi, size=(3, NUM_JOINTS, 3))
    amp = rng.uniform(0, amplitude / 3, size=(3, NUM_JOINTS, 3))
    aa = np.sum(amp * np.sin(2 * np.pi * freq * t[:, None, None, None] + phase), axis=1)
    rest = default_rest_joints()
    root = rest[0] + 0.3 * np.stack([np.sin(0.3 * t), 0.05 * np.sin(1.1 * t), np.cos(0.2 * t) - 1], -1)
    return SimpleMotion(fps=float(fps), rotations=quat_from_axis_angle(aa), root=root, rest_joints=rest)


def body_rates(quats: np.ndarray, fps: float) -> np.ndarray:
    """Body-frame angular velocity (T, S, 3) rad/s from orientations (T, S, 4) (forward
    differences, the last frame repeats the previous rate)."""
    if quats.shape[0] < 2:
        return np.zeros(quats.shape[:-1] + (3,))
    dq = quat_multiply(quat_conjugate(quats[:-1]), quats[1:])
    dq = dq * np.where(dq[..., :1] < 0, -1.0, 1.0)  # shortest arc
    w = quat_to_axis_angle(dq) * fps
    return np.concatenate([w, w[-1:]], axis=0)


def simulate_imus(motion, layout: dict[int, int], *, mounting: np.ndarray | None = None,
                  noise: ImuNoise = ImuNoise(), seed: int = 0) -> ImuTrack:
    """IMU signals of ``motion`` (rotations (T,22,4), root (T,3), rest_joints (22,3), fps) for the
    suit ``layout`` {sensor id: joint index}. mounting: (S, 4) or None (identity)."""
    sensors = np.array(sorted(layout), dtype=np.int64)
    joints = np.array([layout[s] for s in sensors], dtype=np.int64)
    S = len(sensors)
    mounting = random_mounting(S, None) if mounting is None else np.asarray(mounting, np.float64)
    positions, glob = forward_kinematics(motion.rotations, motion.root, motion.rest_joints)
    fps = float(motion.fps)
    T = glob.shape[0]
    true_q = quat_normalize(quat_multiply(glob[:, joints], mounting[None]))
    rng = np.random.default_rng(seed)

    # Specific force: what an accelerometer at the joint measures, a - g, in the sensor frame.
    p = positions[:, joints]
    dt = frame_interval_s(fps)
    a = np.gradient(np.gradient(p, dt, axis=0), dt, axis=0) if T >= 3 else np.zeros_like(p)
    f_world = a + np.array([0.0, GRAVITY, 0.0])
    inv = quat_conjugate(true_q)
    acc = quat_rotate(inv, f_world) + rng.normal(0, noise.acc_std, (T, S, 3)) * (noise.acc_std > 0)
    mag = quat_rotate(inv, np.broadcast_to(MAG_WORLD, (T, S, 3)))
    mag = mag + rng.normal(0, noise.mag_std, (T, S, 3)) * (noise.mag_std > 0)
    bias = rng.normal(0, noise.gyro_bias_std, (S, 3)) * (noise.gyro_bias_std > 0)
    gyro = body_rates(true_q, fps) + bias + rng.normal(0, noise.gyro_std, (T, S, 3)) * (noise.gyro_std > 0)

    # Reported orientation: a per-sensor heading drift about world up, plus small jitter.
    drift_rate = rng.normal(0, noise.yaw_drift_std, S) * (noise.yaw_drift_std > 0)
    yaw = np.arange(T)[:, None] / fps * drift_rate[None]
    q_yaw = quat_from_axis_angle(yaw[..., None] * np.array([0.0, 1.0, 0.0]))
    jitter = quat_from_axis_angle(rng.normal(0, noise.orient_std, (T, S, 3)) * (noise.orient_std > 0))
    quats = quat_normalize(quat_multiply(quat_multiply(q_yaw, true_q), jitter))
    return ImuTrack(fps=fps, sensors=sensors, joints=joints, mounting=mounting, quats=quats,
                    true_quats=true_q, gyro=gyro, acc=acc, mag=mag)
