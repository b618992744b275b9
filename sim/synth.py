"""Synthetic sessions with exact ground truth: a motion on a body, seen by a virtual camera.

``livecap synth --motion CLIP.bvh --body SPEC --out S.mcap`` writes a session exactly like a
recorded one (depth stream, optionally a serial IMU suit and the camera's own IMU,
``sim.camera_imu``) plus ground-truth channels: the 22
world joints and local rotations of the body actually rendered, per frame, and the body itself
(attachment ``body.npz``). Same arguments and seed -> same bytes.

The body is posed with the motion's local rotations (identical meaning on any body) and the
root translation scaled by the leg-length ratio (CONVENTIONS.md). The camera looks at the centre
of the performance area, or faces it horizontally at a given pitch.

Options for scenes a real user has: a posture (``sim.postures``: the clip in place, seated on a
chair, crouching), a floor the sensor does not return (``floor=False``: a dark or shiny floor
reads as no depth), and hidden extrinsics (``hide_extrinsics``: the depth stream carries an
identity camera_to_world, as a camera nobody calibrated does, while the ground truth stays in
the world frame and the gt stream's metadata keeps the true ``camera_to_world``).
"""

from __future__ import annotations

import dataclasses
import io
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from live.body.library import Body, load_body, save_body
from live.body.skinning import lbs
from live.core.errors import UserInputError
from live.core.frames import DepthFrame, GroundTruth
from live.core.kinematics import forward_kinematics
from live.core.protocols import StreamInfo
from live.core.skeleton import JOINT_INDEX, pelvis_height
from live.core.timing import frame_offset_ns
from live.motion.cleaning import trim_bind_pose
from live.motion.clips import Motion, resample
from live.motion.rig_mapping import load_motion
from sim.depth_camera import NoiseModel, VirtualDepthCamera, get_preset, look_at_camera
from sim.postures import apply_posture, seat_boxes
from sim.room import Room

#: Session timestamps start here (3 s: room for a 2 s IMU calibration hold before the first frame), so that replayed files never depend on the wall clock.
T0_NS = 3_000_000_000
#: A fixed "start wall time" for synthetic sessions (2026-01-01T00:00:00Z): same seed, same bytes.
SYNTH_WALL_TIME_NS = 1_767_225_600_000_000_000


@dataclass(frozen=True)
class CameraPlacement:
    """Where the camera stands relative to the centre of the performance area (metres, radians).
    yaw 0 = in front of a performer facing +z. pitch None: aimed at the centre, 1 m above the
    floor; else facing the centre horizontally, tilted *down* by pitch (``look_at_camera``'s
    sign; ``livecap synth --pitch`` takes degrees with negative looking down)."""

    distance: float = 3.0
    height: float = 1.2
    yaw: float = 0.0
    pitch: float | None = None

    @staticmethod
    def random(rng: np.random.Generator) -> CameraPlacement:
        return CameraPlacement(distance=float(rng.uniform(1.5, 4.0)), height=float(rng.uniform(0.6, 1.9)),
                               yaw=float(rng.uniform(-np.pi, np.pi)))


def pose_motion_on_body(motion: Motion, body: Body) -> tuple[np.ndarray, np.ndarray]:
    """(root (T,3), joints (T,22,3)) of the body performing the motion: same local rotations,
    root translation scaled by the leg-length ratio (body pelvis height / motion's)."""
    ratio = pelvis_height(body.rest_joints) / max(pelvis_height(motion.rest_joints), 1e-6)
    root = np.asarray(motion.root, np.float64) * ratio
    joints, _ = forward_kinematics(motion.rotations, root, body.rest_joints)
    # Clips keep their file's floor height; put the floor at y = 0: the feet's usual lowest point
    # (5th percentile over frames, robust to jumps) goes to the body's rest foot height.
    feet = [JOINT_INDEX[n] for n in ("left_ankle", "right_ankle", "left_foot", "right_foot")]
    lowest = joints[:, feet, 1].min(axis=1)
    shift = float(np.percentile(lowest, 5)) - float(np.asarray(body.rest_joints)[feet, 1].min())
    root[:, 1] -= shift
    joints[..., 1] -= shift
    return root, joints


def performance_center(joints: np.ndarray) -> np.ndarray:
    """Centre of the area a motion covers (pelvis x/z midrange), at 1 m height."""
    pelvis = joints[:, 0]
    c = 0.5 * (pelvis.min(axis=0) + pelvis.max(axis=0))
    return np.array([c[0], 1.0, c[2]])


@dataclass
class SyntheticScene:
    """A motion on a body in front of a virtual camera; ``frame(i)`` renders frame i."""

    motion: Motion
    body: Body
    camera: VirtualDepthCamera
    root: np.ndarray
    joints: np.ndarray
    room: Room = field(default_factory=Room)
    #: (3,) what was subtracted from the motion to centre it in the room (add it back to compare
    #: with the motion's own coordinates).
    shift: np.ndarray = field(default_factory=lambda: np.zeros(3))
    #: Depth frames carry an identity camera_to_world (the camera's pose is not told).
    hide_extrinsics: bool = False

    @classmethod
    def build(cls, motion: Motion, body: Body, *, camera: str = "oak-d", fps: float | None = None,
              placement: CameraPlacement | None = None, noise: NoiseModel | None = None,
              seed: int = 0, max_range_m: float | None = None, posture: str = "clip", floor: bool = True,
              hide_extrinsics: bool = False) -> SyntheticScene:
        preset = get_preset(camera)
        if max_range_m is not None:
            # Like a depth threshold filter on the device (OAK-D thresholdFilter): farther is 0.
            preset = dataclasses.replace(preset, max_range_m=float(max_range_m))
        motion = apply_posture(resample(motion, fps or preset.fps), posture)
        root, joints = pose_motion_on_body(motion, body)
        # The room is centred on the origin: move the performance area there (x, z only).
        center = performance_center(joints)
        shift = np.array([center[0], 0.0, center[2]])
        root, joints = root - shift, joints - shift
        placement = placement or CameraPlacement()
        c2w = look_at_camera(placement.distance, placement.height, placement.yaw, placement.pitch,
                             target=(0.0, 1.0, 0.0))
        # Grow the room so the camera stands inside it, whatever the placement.
        reach = 2.0 * (np.abs(c2w[[0, 2], 3]).max() + 0.5)
        room = Room(width=max(Room().width, reach), depth=max(Room().depth, reach), floor=floor,
                    boxes=seat_boxes(joints) if posture == "seated" else ())
        cam = VirtualDepthCamera(preset, c2w, noise=noise if noise is not None else NoiseModel(), seed=seed)
        return cls(motion=motion, body=body, camera=cam, root=root, joints=joints, room=room, shift=shift,
                   hide_extrinsics=hide_extrinsics)

    @property
    def num_frames(self) -> int:
        return len(self.root)

    def vertices(self, i: int) -> np.ndarray:
        return lbs(self.body.vertices, self.body.weights, self.body.rest_joints,
                   self.motion.rotations[i], self.root[i])[0]

    def truth(self, i: int, t_ns: int) -> GroundTruth:
        return GroundTruth(t_ns=t_ns, joints=self.joints[i].astype(np.float32),
                           rotations=np.asarray(self.motion.rotations[i], np.float32),
                           root=self.root[i].astype(np.float32))

    @property
    def told_camera_to_world(self) -> np.ndarray:
        """(4, 4) the camera_to_world the depth stream carries: the true one, or identity when
        the extrinsics are hidden."""
        return np.eye(4) if self.hide_extrinsics else self.camera.camera_to_world

    def depth(self, i: int, t_ns: int, sensor: str = "cam") -> DepthFrame:
        depth_mm = self.camera.render(self.vertices(i), self.body.faces, room=self.room)
        return DepthFrame(t_ns=t_ns, sensor=sensor, camera_to_world=self.told_camera_to_world,
                          depth_mm=depth_mm, intrinsics=self.camera.intrinsics)

    def depth_stream(self, sensor: str = "cam") -> StreamInfo:
        p = self.camera.preset
        return StreamInfo(sensor, "depth", {
            "intrinsics": self.camera.intrinsics.tolist(), "camera_to_world": self.told_camera_to_world.tolist(),
            "width": p.width, "height": p.height, "fps": float(self.motion.fps), "camera": p.name,
            "simulated": True})

    def truth_stream(self, meta: dict) -> StreamInfo:
        """The gt stream; with hidden extrinsics its metadata keeps the true camera_to_world
        (what the depth stream's camera is in the ground truth's world)."""
        if self.hide_extrinsics:
            meta = {**meta, "camera_to_world": self.camera.camera_to_world.tolist()}
        return StreamInfo("gt", "gt", meta)


def body_npz_bytes(body: Body) -> bytes:
    """The body file (CONVENTIONS.md contract) as bytes, written by live.body.library.save_body."""
    buf = io.BytesIO()
    save_body(buf, body)
    return buf.getvalue()


@dataclass
class SynthOptions:
    motion: str
    body: str = "performer"
    camera: str = "oak-d"
    seconds: float | None = None
    fps: float | None = None
    seed: int = 0
    imu: str | None = None
    start_s: float = 0.0
    placement: CameraPlacement = field(default_factory=CameraPlacement)
    noise: bool = True
    max_range_m: float | None = None
    camera_imu: bool = False  # also the camera's own IMU (sim.camera_imu)
    posture: str = "clip"  # sim.postures.POSTURES
    floor: bool = True  # False: the sensor returns nothing from the floor
    hide_extrinsics: bool = False


def synthesize(opts: SynthOptions, out: str | Path, progress: Callable[[int, int], None] | None = None) -> dict:
    """Write a synthetic session; returns a summary dict."""
    from live.io.session import SessionWriter

    motion = trim_bind_pose(load_motion(opts.motion))  # a performer starts in motion, not in a bind pose
    body = load_body(opts.body)
    scene = SyntheticScene.build(motion, body, camera=opts.camera, fps=opts.fps, placement=opts.placement,
                                 noise=NoiseModel() if opts.noise else NoiseModel.none(), seed=opts.seed,
                                 max_range_m=opts.max_range_m, posture=opts.posture, floor=opts.floor,
                                 hide_extrinsics=opts.hide_extrinsics)
    fps = float(scene.motion.fps)
    first = int(round(opts.start_s * fps))
    last = scene.num_frames if opts.seconds is None else min(scene.num_frames, first + int(round(opts.seconds * fps)))
    if last <= first:
        raise UserInputError(f"the motion has {scene.num_frames} frames at {fps:g} fps: nothing to render "
                             f"from {opts.start_s:g} s")
    streams = [scene.depth_stream(), scene.truth_stream({"body": body.name, "motion": Path(opts.motion).name})]
    suit = None
    if opts.imu:
        from sim.imu_stream import ImuStreamer

        suit = ImuStreamer(scene, protocol=opts.imu, seed=opts.seed)
        streams.append(suit.stream_info())
    camera_imu = None
    if opts.camera_imu:
        from sim.camera_imu import CameraImu

        # Like an OAK's <camera>_imu stream, from the true pose (also when the depth stream hides it);
        # the camera was on, and still, for a second before it streamed depth.
        camera_imu = CameraImu(scene.camera.camera_to_world, camera=streams[0].name, seed=opts.seed,
                               start_ns=T0_NS - 1_000_000_000)
        streams.append(camera_imu.stream_info())
    extra = {"synthetic": {"motion": Path(opts.motion).name, "body": opts.body, "camera": opts.camera,
                           "seed": opts.seed, "placement": asdict(opts.placement), "noise": opts.noise,
                           "max_range_m": opts.max_range_m}}
    # Keys of the room options only when set: sessions without them keep their bytes.
    for key, default in (("posture", "clip"), ("floor", True), ("hide_extrinsics", False), ("camera_imu", False)):
        if getattr(opts, key) != default:
            extra["synthetic"][key] = getattr(opts, key)
    with SessionWriter(out, streams, extra=extra, start_wall_time_ns=SYNTH_WALL_TIME_NS) as writer:
        writer.attach("body.npz", body_npz_bytes(body), create_time_ns=SYNTH_WALL_TIME_NS)
        for k, i in enumerate(range(first, last)):
            t_ns = T0_NS + frame_offset_ns(k, fps)
            side = [] if suit is None else list(suit.packets_until(i, t_ns))
            if camera_imu is not None:  # both side streams in time order
                side = sorted(side + camera_imu.packets_until(t_ns), key=lambda p: p.t_ns)
            for packet in side:
                writer.write(packet)
            writer.write(scene.truth(i, t_ns))
            writer.write(scene.depth(i, t_ns))
            if progress is not None:
                progress(k + 1, last - first)
    return {"frames": last - first, "fps": fps, "body": body.name, "camera": opts.camera, "out": str(out)}


class SimulatedSource:
    """``sim:CLIP.bvh``: the virtual camera rendering a motion live (timed like a real camera
    unless speed is None), emitting depth frames and their ground truth."""

    def __init__(self, motion_path: str, *, body: str = "performer", camera: str = "oak-d",
                 speed: float | None = 1.0, seed: int = 0, name: str = "sim", loop: bool = False):
        path = Path(motion_path)
        if not path.is_file():
            raise UserInputError(f"no such motion file: {path}")
        self.scene = SyntheticScene.build(trim_bind_pose(load_motion(path)), load_body(body), camera=camera,
                                          seed=seed)
        self.name = name
        self.speed = speed
        self.loop = loop
        self._counters = {"frames": 0}

    @classmethod
    def from_spec(cls, target: str, options: dict, speed: float | None = 1.0) -> SimulatedSource:
        return cls(target, body=options.get("body", "performer"), camera=options.get("camera", "oak-d"),
                   seed=int(options.get("seed", 0)), speed=speed, loop=options.get("loop", "0") in ("1", "true"))

    @property
    def counters(self) -> dict[str, int]:
        return dict(self._counters)

    def streams(self) -> list[StreamInfo]:
        return [self.scene.depth_stream(self.name), StreamInfo("gt", "gt", {"body": self.scene.body.name})]

    def run(self, emit: Callable[[object], None], stop: threading.Event) -> None:
        period = 1.0 / self.scene.motion.fps
        start = time.monotonic()
        k = 0
        while not stop.is_set():
            i = k % self.scene.num_frames
            if k >= self.scene.num_frames and not self.loop:
                return
            if self.speed:
                delay = start + k * period / self.speed - time.monotonic()
                if delay > 0 and stop.wait(delay):
                    return
            t_ns = time.monotonic_ns()
            emit(self.scene.truth(i, t_ns))
            emit(self.scene.depth(i, t_ns, sensor=self.name))
            self._counters["frames"] += 1
            k += 1
