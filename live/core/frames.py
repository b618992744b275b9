"""Typed records that cross module boundaries: what sensors produce and what stages emit.

Every record carries ``t_ns``: the host monotonic clock (time.monotonic_ns()) at which the sample
was taken (device clocks are converted by the driver). Arrays follow ../shared/CONVENTIONS.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from live.core.skeleton import NUM_JOINTS


def _identity4() -> np.ndarray:
    return np.eye(4, dtype=np.float64)


@dataclass(frozen=True, slots=True)
class DepthFrame:
    """One depth sample: a camera-frame point cloud and/or a depth image with its intrinsics.

    points: (N, 3) float32 metres, camera frame (OpenCV axes). depth_mm: (H, W) uint16
    millimetres, 0 = no data. intrinsics: (3, 3) float64. camera_to_world: (4, 4) float64.
    """

    t_ns: int
    sensor: str
    camera_to_world: np.ndarray = field(default_factory=_identity4)
    points: np.ndarray | None = None
    depth_mm: np.ndarray | None = None
    intrinsics: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.points is None and self.depth_mm is None:
            raise ValueError("a DepthFrame needs points or a depth image")
        if self.depth_mm is not None and self.intrinsics is None:
            raise ValueError("a depth image needs its 3x3 intrinsics")

    def cloud(self) -> np.ndarray:
        """(N, 3) float32 camera-frame points (unprojects the depth image when there is one)."""
        if self.points is not None:
            return self.points
        from live.core.depth import depth_to_points

        assert self.depth_mm is not None and self.intrinsics is not None  # checked in __post_init__
        return depth_to_points(self.depth_mm, self.intrinsics)


@dataclass(frozen=True, slots=True)
class MocapPacket:
    """One read from a motion-capture device: its raw bytes and/or decoded per-sensor samples.

    sensors: (S,) int64 sensor ids (a 48-bit MAC or a 32-bit Xsens DeviceId fits); quats: (S, 4)
    float32 (w, x, y, z) sensor-to-world orientations; counter (S,) int64, acc (S, 3) m/s^2,
    gyro (S, 3) rad/s, mag (S, 3) when sent.
    """

    t_ns: int
    device: str
    raw: bytes = b""
    sensors: np.ndarray | None = None
    quats: np.ndarray | None = None
    counter: np.ndarray | None = None
    acc: np.ndarray | None = None
    gyro: np.ndarray | None = None
    mag: np.ndarray | None = None

    @property
    def decoded(self) -> bool:
        return self.sensors is not None and self.quats is not None


@dataclass(frozen=True, slots=True)
class SkeletonFrame:
    """22 world joints (metres) with per-joint confidence in [0, 1]; t_ns is the sensor time.
    camera_to_world: (4, 4) the camera -> world the joints were solved in (the depth frame's own,
    or the one the skeleton stage estimated for a camera without extrinsics), or None when the
    skeleton does not come from a camera."""

    t_ns: int
    joints: np.ndarray
    confidence: np.ndarray
    camera_to_world: np.ndarray | None = None

    def __post_init__(self) -> None:
        if np.shape(self.joints) != (NUM_JOINTS, 3) or np.shape(self.confidence) != (NUM_JOINTS,):
            raise ValueError("a SkeletonFrame holds (22, 3) joints and (22,) confidences")
        if self.camera_to_world is not None and np.shape(self.camera_to_world) != (4, 4):
            raise ValueError("a SkeletonFrame's camera_to_world is (4, 4)")


@dataclass(frozen=True, slots=True)
class AvatarPose:
    """The avatar's pose: root (3,) world position and (22, 4) local rotations (w, x, y, z).

    joints: (22, 3) world joints of the posed avatar, when computed; vertices: (V, 3) posed mesh
    vertices, when asked for.
    """

    t_ns: int
    root: np.ndarray
    rotations: np.ndarray
    joints: np.ndarray | None = None
    vertices: np.ndarray | None = None


@dataclass(frozen=True, slots=True)
class GroundTruth:
    """What a synthetic session actually rendered at t_ns: world joints (22, 3), local rotations
    (22, 4), root (3,). The body itself is stored once per session (see sim.synth)."""

    t_ns: int
    joints: np.ndarray
    rotations: np.ndarray
    root: np.ndarray


@dataclass(slots=True)
class FrameResult:
    """Everything the pipeline produced for one sensor frame, handed to every sink.

    t_ns is the sensor timestamp of the frame; latency_ms maps stage name -> milliseconds spent
    (stage timings only); points: how many depth points the cloud stage turned into a world cloud.
    """

    t_ns: int
    depth: DepthFrame | None = None
    skeleton: SkeletonFrame | None = None
    avatar: AvatarPose | None = None
    mocap: MocapPacket | None = None
    truth: GroundTruth | None = None
    latency_ms: dict[str, float] = field(default_factory=dict)
    points: int | None = None
