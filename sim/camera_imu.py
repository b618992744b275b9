"""The virtual camera's own IMU (``livecap synth --camera-imu``): a still OAK's accelerometer and gyro.

A camera standing still reads specific force +g along world up and no rotation; ``CameraImu``
turns a camera_to_world into those samples, in the camera's axes (OpenCV: +x right, +y down,
+z forward) like the OAK driver's ``<camera>_imu`` stream, with white noise and a constant
per-axis bias on both sensors (a BNO085-class part after factory calibration). The samples are
MocapPackets of one sensor (id 0) without orientations, one per sample, at ``rate_hz``,
starting ``lead_s`` before the first depth frame: a camera is on (and still) before it streams
depth. Same camera, seed and rate -> same samples; its random stream is its own, so adding it
leaves every other stream of a session unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from live.core.frames import MocapPacket
from live.core.gravity import CAMERA_IMU_SUFFIX, STANDARD_GRAVITY
from live.core.protocols import StreamInfo
from live.core.timing import frame_offset_ns

#: Tag mixed into the seed so that the camera IMU draws its own random numbers.
_SEED_TAG = 0xCA1


@dataclass(frozen=True)
class CameraImuNoise:
    """Per-axis standard deviations: white noise per sample and a constant bias (m/s^2, rad/s)."""

    acc_std: float = 0.03
    acc_bias_std: float = 0.03
    gyro_std: float = 0.003
    gyro_bias_std: float = 0.002

    @staticmethod
    def none() -> CameraImuNoise:
        return CameraImuNoise(0.0, 0.0, 0.0, 0.0)


def specific_force_in_camera(camera_to_world: np.ndarray, g: float = STANDARD_GRAVITY) -> np.ndarray:
    """(3,) what a still accelerometer reads in camera axes: +g along world up (+y)."""
    rotation = np.asarray(camera_to_world, np.float64)[:3, :3]
    return g * rotation.T @ np.array([0.0, 1.0, 0.0])


class CameraImu:
    """Samples of a still camera's IMU; ``packets_until(t_ns)`` hands out those not yet given up to
    t_ns (inclusive), in time order."""

    def __init__(self, camera_to_world: np.ndarray, *, camera: str = "cam", rate_hz: float = 100.0,
                 noise: CameraImuNoise | None = None, seed: int = 0, start_ns: int = 0):
        if rate_hz <= 0:
            raise ValueError(f"camera IMU rate {rate_hz} must be positive")
        self.camera = camera
        self.name = camera + CAMERA_IMU_SUFFIX
        self.rate_hz = float(rate_hz)
        self.noise = noise or CameraImuNoise()
        self.start_ns = int(start_ns)
        self.reading = specific_force_in_camera(camera_to_world)
        self._rng = np.random.default_rng([int(seed), _SEED_TAG])
        n = self.noise
        self.acc_bias = self._rng.normal(0.0, n.acc_bias_std, 3)
        self.gyro_bias = self._rng.normal(0.0, n.gyro_bias_std, 3)
        self._k = 0

    def stream_info(self) -> StreamInfo:
        """Like the OAK driver's IMU stream: vectors in the camera's axes, no orientation."""
        return StreamInfo(self.name, "imu", {"imu": "simulated", "rate_hz": self.rate_hz, "orientation": False,
                                             "frame": "camera", "camera": self.camera, "simulated": True})

    def packets_until(self, t_ns: int) -> list[MocapPacket]:
        out = []
        n = self.noise
        while (t := self.start_ns + frame_offset_ns(self._k, self.rate_hz)) <= t_ns:
            acc = self.reading + self.acc_bias + self._rng.normal(0.0, n.acc_std, 3)
            gyro = self.gyro_bias + self._rng.normal(0.0, n.gyro_std, 3)
            out.append(MocapPacket(t_ns=t, device=self.name, sensors=np.zeros(1, np.int32),
                                   counter=np.array([self._k], np.int64), acc=acc[None], gyro=gyro[None]))
            self._k += 1
        return out


__all__ = ["CameraImu", "CameraImuNoise", "specific_force_in_camera"]
