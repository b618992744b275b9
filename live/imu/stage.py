"""Pipeline stages for IMU suits: ``ImuSkeletonStage`` (suit alone) and ``FusionStage`` (suit +
depth skeleton), and ``build_stages`` to assemble depth-only / IMU-only / fused pipelines.

Both stages see every mocap packet through ``observe`` (in stream order, so the suit is always
up to date when a depth frame is processed), calibrate themselves from the first held pose
unless given a Calibration, and on ``process(result)`` pose the skeleton at ``result.t_ns``:
each sensor's orientation is interpolated between its two samples around that time (or
extrapolated at most half a sample past the newest one).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from live.core.frames import DepthFrame, FrameResult, MocapPacket, SkeletonFrame
from live.core.rotations import quat_slerp
from live.core.skeleton import default_rest_joints
from live.imu.calibration import Calibration, CalibrationCollector, calibrate
from live.imu.fusion import Fuser
from live.imu.layout import SuitLayout, load_suit_layout
from live.imu.suit_skeleton import SuitPose, SuitSolver

MODES = ("depth", "imu", "fused")


class SensorBuffer:
    """The two newest samples of each sensor of a layout; ``at(t_ns)`` -> (S, 4) or None while a
    sensor has not been heard from."""

    def __init__(self, layout: SuitLayout):
        self.rows = layout.index_of()
        S = layout.size
        self.t = np.full((2, S), -1, dtype=np.int64)  # [previous, newest]
        self.q = np.zeros((2, S, 4))
        self.q[..., 0] = 1.0
        self.samples = 0

    def add(self, packet: MocapPacket) -> int:
        n = 0
        for s, q in zip(packet.sensors.tolist(), np.asarray(packet.quats, np.float64)):
            i = self.rows.get(int(s))
            if i is None or not np.all(np.isfinite(q)):
                continue
            self.t[0, i], self.q[0, i] = self.t[1, i], self.q[1, i]
            self.t[1, i], self.q[1, i] = packet.t_ns, q
            n += 1
        self.samples += n
        return n

    @property
    def ready(self) -> bool:
        return bool(np.all(self.t[1] >= 0))

    def at(self, t_ns: int) -> np.ndarray | None:
        if not self.ready:
            return None
        t0, t1 = self.t[0].astype(np.float64), self.t[1].astype(np.float64)
        span = np.where((self.t[0] >= 0) & (t1 > t0), t1 - t0, 1.0)
        u = np.where(self.t[0] >= 0, (t_ns - t0) / span, 1.0)
        u = np.clip(u, 0.0, 1.5)[:, None]
        return quat_slerp(self.q[0], self.q[1], u)


class WindowCalibrator:
    """Calibrates on the packets of a known hold (an imported take's, found at import): once the
    stream passes the window's end, ``feed`` returns the Calibration of the packets inside it."""

    def __init__(self, layout: SuitLayout, pose: str, rest_joints: np.ndarray, window_ns: tuple[int, int], *,
                 per_sensor_heading: bool = False):
        self.layout, self.pose, self.rest_joints = layout, pose, rest_joints
        self.window = (int(window_ns[0]), int(window_ns[1]))
        self.per_sensor_heading = per_sensor_heading
        self.packets: list[MocapPacket] = []
        self.done = False

    def feed(self, packet: MocapPacket) -> Calibration | None:
        if self.done:
            return None
        if packet.t_ns <= self.window[1]:
            if packet.t_ns >= self.window[0]:
                self.packets.append(packet)
            return None
        self.done = True
        return calibrate(self.packets, self.layout, self.pose, self.rest_joints,
                         per_sensor_heading=self.per_sensor_heading, max_spread_deg=20.0)


class _SuitStageBase:
    """Shared observe/calibration logic."""

    def __init__(self, layout, calibration: Calibration | None, *, pose: str, hold_s: float,
                 min_hold_s: float | None, rest_joints: np.ndarray | None, height: float, device: str | None,
                 window_ns: tuple[int, int] | None = None, per_sensor_heading: bool = False):
        self.layout = load_suit_layout(layout)
        self.rest_joints = np.asarray(default_rest_joints(height) if rest_joints is None else rest_joints, np.float64)
        self.device = device
        self.buffer = SensorBuffer(self.layout)
        self.calibration = calibration
        if calibration is not None:
            self.collector = None
        elif window_ns is not None:
            self.collector = WindowCalibrator(self.layout, pose, self.rest_joints, window_ns,
                                              per_sensor_heading=per_sensor_heading)
        else:
            self.collector = CalibrationCollector(self.layout, pose, self.rest_joints, hold_s=hold_s,
                                                  min_hold_s=min_hold_s, per_sensor_heading=per_sensor_heading)
        self.counters = {"packets": 0, "samples": 0, "skeletons": 0, "uncalibrated": 0}
        self.last_pose: SuitPose | None = None

    def observe(self, frame: object) -> None:
        if not isinstance(frame, MocapPacket) or not frame.decoded or frame.quats is None:
            return  # raw bytes not decoded, or an IMU without orientations (a camera's)
        if self.device is not None and frame.device != self.device:
            return
        self.counters["packets"] += 1
        self.counters["samples"] += self.buffer.add(frame)
        if self.calibration is None:
            cal = self.collector.feed(frame)
            if cal is not None:
                self.calibration = cal
                self._calibrated(cal)

    def _calibrated(self, cal: Calibration) -> None:
        raise NotImplementedError


class ImuSkeletonStage(_SuitStageBase):
    """Stage ``imu``: the suit alone -> ``result.skeleton``. The rest skeleton comes from
    ``rest_joints`` or the performer's ``height``; the root from foot contacts, starting at
    ``start`` (3,) facing ``world_yaw`` (radians) as during the calibration hold.

    layout: a SuitLayout or anything load_suit_layout takes; calibration: a saved Calibration
    (None: calibrate on the first ``pose`` held still for ``hold_s`` s, or at least
    ``min_hold_s`` s before the performer moves); device: only packets of this stream."""

    name = "imu"

    def __init__(self, layout=None, calibration: Calibration | None = None, *, pose: str = "tpose",
                 hold_s: float = 2.0, min_hold_s: float | None = None, rest_joints: np.ndarray | None = None,
                 height: float = 1.75, world_yaw: float = 0.0, start: np.ndarray | None = None,
                 device: str | None = None, window_ns: tuple[int, int] | None = None,
                 per_sensor_heading: bool = False):
        super().__init__(layout, calibration, pose=pose, hold_s=hold_s, min_hold_s=min_hold_s,
                         rest_joints=rest_joints, height=height, device=device, window_ns=window_ns,
                         per_sensor_heading=per_sensor_heading)
        self.world_yaw = world_yaw
        self.start = start
        self.solver = None
        if calibration is not None:
            self._calibrated(calibration)

    def _calibrated(self, cal: Calibration) -> None:
        self.solver = SuitSolver(cal, self.rest_joints, world_yaw=self.world_yaw, start=self.start)

    def process(self, result: FrameResult) -> bool:
        if self.solver is None:
            self.counters["uncalibrated"] += 1
            return False
        if result.mocap is not None and result.depth is None and not self._has_samples(result.mocap):
            return False
        quats = self.buffer.at(result.t_ns)
        if quats is None:
            return False
        pose = self.solver.solve(quats, t_ns=result.t_ns)
        self.last_pose = pose
        conf = np.where(self.solver.plan.source >= 0, 1.0, 0.7)
        result.skeleton = SkeletonFrame(t_ns=result.t_ns, joints=pose.joints.astype(np.float32),
                                        confidence=conf.astype(np.float32))
        self.counters["skeletons"] += 1
        return True

    def _has_samples(self, packet: MocapPacket) -> bool:
        return packet.sensors is not None and len(packet.sensors) > 0 and (
            self.device is None or packet.device == self.device)


class FusionStage(_SuitStageBase):
    """Stage ``fusion``: runs after a depth skeleton stage and replaces ``result.skeleton`` with
    the fused one (the depth skeleton stays in ``depth_skeleton``). Before calibration the depth
    skeleton passes through untouched; frames without a person use the suit with the heading
    and proportions learned so far. Options of live.imu.fusion.Fuser via ``fuser_options``."""

    name = "fusion"

    def __init__(self, layout=None, calibration: Calibration | None = None, *, pose: str = "tpose",
                 hold_s: float = 2.0, min_hold_s: float | None = None, rest_joints: np.ndarray | None = None,
                 height: float = 1.75, device: str | None = None, fuser_options: dict | None = None,
                 window_ns: tuple[int, int] | None = None, per_sensor_heading: bool = False):
        super().__init__(layout, calibration, pose=pose, hold_s=hold_s, min_hold_s=min_hold_s,
                         rest_joints=rest_joints, height=height, device=device, window_ns=window_ns,
                         per_sensor_heading=per_sensor_heading)
        self.fuser_options = dict(fuser_options or {})
        self.fuser: Fuser | None = None
        self.depth_skeleton: SkeletonFrame | None = None
        if calibration is not None:
            self._calibrated(calibration)

    def _calibrated(self, cal: Calibration) -> None:
        self.fuser = Fuser(cal, **self.fuser_options)

    def process(self, result: FrameResult) -> bool:
        self.depth_skeleton = result.skeleton
        if self.fuser is None:
            self.counters["uncalibrated"] += 1
            return False
        quats = self.buffer.at(result.t_ns)
        if quats is None:
            return False
        image, c2w = depth_image_of(result)
        fused = self.fuser.update(quats, result.t_ns, result.skeleton, image, c2w)
        self.counters.update(self.fuser.counters)  # depth frames, suit-only frames, outliers, root jumps
        if fused is None:
            return False
        pose, conf = fused
        self.last_pose = pose
        result.skeleton = SkeletonFrame(t_ns=result.t_ns, joints=pose.joints.astype(np.float32),
                                        confidence=conf.astype(np.float32))
        self.counters["skeletons"] += 1
        return True


def depth_image_of(result: FrameResult) -> tuple[DepthFrame | None, np.ndarray | None]:
    """The depth image the frame's skeleton was estimated from, and the camera_to_world its joints
    were solved in; (None, None) when there is no image or the skeleton belongs to another frame
    (a lagging temporal model's)."""
    depth, skeleton = result.depth, result.skeleton
    if depth is None or skeleton is None or depth.depth_mm is None or depth.intrinsics is None:
        return None, None
    if skeleton.t_ns != depth.t_ns:
        return None, None
    c2w = skeleton.camera_to_world if skeleton.camera_to_world is not None else depth.camera_to_world
    return depth, np.asarray(c2w, np.float64)


def is_suit_stream(stream) -> bool:
    """A suit's stream: serial bytes, or decoded samples (``imu``) with a layout (an imported
    recording); a camera's own IMU is not one."""
    return stream.kind == "serial" or (stream.kind == "imu" and isinstance(stream.meta.get("layout"), dict))


def suit_options_from_stream(meta: dict) -> dict:
    """Stage keyword arguments from a suit stream's metadata (a synthetic session records its
    layout and calibration hold there, an imported one its layout and its calibration: the
    file's, or the window of the take's hold): layout, pose, hold_s, min_hold_s, calibration,
    window_ns, per_sensor_heading."""
    out: dict = {}
    if isinstance(meta.get("layout"), dict):
        out["layout"] = load_suit_layout(meta["layout"])
    cal = meta.get("calibration")
    if isinstance(cal, dict):
        out["pose"] = cal.get("pose", "tpose")
        if isinstance(cal.get("calibration"), dict):
            out["calibration"] = Calibration.from_json(cal["calibration"])
        window = cal.get("window_ns")
        if isinstance(window, list) and len(window) == 2 and all(isinstance(v, int) for v in window):
            out["window_ns"] = (window[0], window[1])
        if cal.get("per_sensor_heading") is True:
            out["per_sensor_heading"] = True
        if "hold_s" in cal:
            # Calibrate before the recorded hold ends (the blend into the motion follows it).
            out["hold_s"] = 0.8 * float(cal["hold_s"])
            out["min_hold_s"] = 0.5 * float(cal["hold_s"])
    return out


def build_stages(mode: str, *, layout=None, calibration: Calibration | str | Path | None = None,
                 pose: str = "tpose", hold_s: float = 2.0, min_hold_s: float | None = None,
                 height: float = 1.75, rest_joints: np.ndarray | None = None, depth_stage=None,
                 model_path: str | Path | None = None, device: str | None = None,
                 stream_meta: dict | None = None, fuser_options: dict | None = None) -> list:
    """The stages of one capture mode: "depth" (the skeleton regressor), "imu" (the suit alone)
    or "fused" (the regressor, then fusion). depth_stage: a ready depth skeleton stage (default
    models.skeleton.runtime.SkeletonStage(model_path)); calibration: a Calibration or its JSON
    file (default: calibrate on the held pose); stream_meta: the suit stream's metadata, whose
    layout / calibration hold fill in what is not given."""
    if mode not in MODES:
        from live.core.errors import UserInputError

        raise UserInputError(f"unknown capture mode {mode!r}; expected one of {MODES}")
    opts = {"layout": layout, "pose": pose, "hold_s": hold_s, "min_hold_s": min_hold_s}
    if stream_meta:
        for key, value in suit_options_from_stream(stream_meta).items():
            if key == "layout" and layout is not None:
                continue
            if key == "calibration":
                calibration = calibration if calibration is not None else value
                continue
            opts[key] = value
    if isinstance(calibration, (str, Path)):
        calibration = Calibration.load(calibration)

    def depth():
        if depth_stage is not None:
            return depth_stage
        from models.skeleton.runtime import SkeletonStage

        return SkeletonStage(model_path)

    common = dict(calibration=calibration, rest_joints=rest_joints, height=height, device=device, **opts)
    if mode == "depth":
        return [depth()]
    if mode == "imu":
        return [ImuSkeletonStage(**common)]
    return [depth(), FusionStage(fuser_options=fuser_options, **common)]
