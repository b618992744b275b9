"""Sessions for the depth + IMU fusion study (research/imu_fusion_eval.py): made, run through the
depth skeleton stage once, cached.

A case is a CMU clip on a body from the library, seen by the virtual OAK-D from a placement drawn
from its seed, with the simulated Xsens suit (sim.imu_stream: 10 deg pocket errors, a calibration
T-pose held with ``POSE_ERROR_DEG`` of error per joint, jitter, heading drift, gyro noise). A case
may lose a limb for ``loss_s`` seconds from ``loss_start_s``: the depth of both legs (everything
below the hips: legs out of frame) or of one arm (within 10 cm of its bones: an occluder that
returns no depth: within ``ARM_RADIUS_M`` of its bones from a third down the upper arm) is
blanked in those frames.

``load_case(case)`` returns a ``CaseData``: every suit packet decoded (in arrival order) and,
per camera frame, the depth skeleton (NaN rows where the stage found nobody), its confidence, the
ground truth and the depth image itself (the fusion stage reads it: is a limb seen where the suit
puts it), cached as a compressed .npz under ``.cache/imu_fusion/<key>``, the key a hash of the
skeleton stage's model files (the regressor and the temporal model beside it) and of
``CACHE_VERSION``: a new shipped model makes new depth skeletons, never stale ones.
"""

from __future__ import annotations

import hashlib
import json
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from live.body.library import load_body
from live.core import assets
from live.core.depth import depth_to_points, points_to_world
from live.core.frames import DepthFrame, FrameResult, GroundTruth, MocapPacket
from live.core.skeleton import JOINT_INDEX, NUM_JOINTS
from live.core.timing import frame_offset_ns
from live.io.session import SessionReader, SessionWriter
from live.motion.cleaning import trim_bind_pose
from live.motion.rig_mapping import load_motion
from live.pipeline.runner import Pipeline
from sim.imu_stream import ImuStreamer
from sim.replay import ReplaySource
from sim.synth import SYNTH_WALL_TIME_NS, T0_NS, CameraPlacement, SyntheticScene, body_npz_bytes

CACHE = assets.cache_dir("imu_fusion")
#: Bumped when what a case holds changes (its arrays, the session it is made from).
CACHE_VERSION = 2
#: Per-axis std (deg) of how far each joint of the performer's held calibration pose is from the
#: ideal T-pose: what the calibration then takes for the pockets' mounting.
POSE_ERROR_DEG = 5.0
#: Radius of the blanked tube around a lost arm's bones (an arm's own ~5 cm plus a margin).
ARM_RADIUS_M = 0.08
LOSSES = ("none", "legs", "left_arm", "right_arm")
#: The joints a loss hides, and those it is scored on.
LOST_JOINTS = {
    "legs": tuple(JOINT_INDEX[f"{s}_{j}"] for s in ("left", "right") for j in ("knee", "ankle", "foot")),
    "left_arm": tuple(JOINT_INDEX[f"left_{j}"] for j in ("elbow", "wrist")),
    "right_arm": tuple(JOINT_INDEX[f"right_{j}"] for j in ("elbow", "wrist")),
}


@dataclass(frozen=True)
class Case:
    clip: str
    body: str
    seed: int
    loss: str = "none"
    loss_start_s: float = 1.0
    loss_s: float = 2.0

    @property
    def name(self) -> str:
        return f"{Path(self.clip).stem}_{self.body}_s{self.seed}_{self.loss}"

    def placement(self) -> CameraPlacement:
        rng = np.random.default_rng([self.seed, 0x1F0])
        return CameraPlacement(distance=float(rng.uniform(2.2, 3.5)), height=float(rng.uniform(0.9, 1.6)),
                               yaw=float(np.radians(rng.uniform(-50.0, 50.0))))

    def lost(self, t_s: float) -> bool:
        return self.loss != "none" and self.loss_start_s <= t_s < self.loss_start_s + self.loss_s


@dataclass
class CaseData:
    """One case, run through the depth stage. Packets: t (P,), per packet its samples
    sensors/quats (concatenated, count (P,)). Frames: t (F,), depth (F, 22, 3) NaN rows where no
    skeleton, conf (F, 22), truth (F, 22, 3), lost (F,) frames in the loss window. meta: the suit
    stream's metadata; start_root (3,), start_yaw: where the performer stood and faced at the
    first frame (the marked start of an IMU-only run). The camera: depth_mm (F, H, W) uint16 (the
    frames as the skeleton stage saw them, a lost limb blanked), intrinsics (3, 3),
    camera_to_world (F, 4, 4)."""

    case: Case
    packet_t: np.ndarray
    packet_count: np.ndarray
    sensors: np.ndarray
    quats: np.ndarray
    t: np.ndarray
    depth: np.ndarray
    conf: np.ndarray
    truth: np.ndarray
    lost: np.ndarray
    meta: dict
    start_root: np.ndarray
    start_yaw: float
    depth_mm: np.ndarray
    intrinsics: np.ndarray
    camera_to_world: np.ndarray

    def depth_frame(self, f: int) -> DepthFrame:
        return DepthFrame(t_ns=int(self.t[f]), sensor="depth", camera_to_world=self.camera_to_world[f],
                          depth_mm=self.depth_mm[f], intrinsics=self.intrinsics)

    def packets(self) -> list[MocapPacket]:
        ends = np.cumsum(self.packet_count)
        starts = ends - self.packet_count
        return [MocapPacket(t_ns=int(t), device="suit", sensors=self.sensors[a:b], quats=self.quats[a:b])
                for t, a, b in zip(self.packet_t, starts, ends)]


def blank_limb(frame: DepthFrame, joints: np.ndarray, loss: str) -> DepthFrame:
    """The depth frame with the lost limb's pixels set to 0 (no data)."""
    depth = frame.depth_mm.copy()
    v, u = np.nonzero(depth)
    world = points_to_world(depth_to_points(depth, frame.intrinsics), frame.camera_to_world).astype(np.float64)
    if loss == "legs":
        gone = world[:, 1] < joints[[JOINT_INDEX["left_hip"], JOINT_INDEX["right_hip"]], 1].min()
    else:
        side = loss.split("_")[0]
        sh, el, wr = (joints[JOINT_INDEX[f"{side}_{j}"]] for j in ("shoulder", "elbow", "wrist"))
        gone = np.zeros(len(world), bool)
        # From a third down the upper arm (the shoulder joint is the torso's) to past the hand.
        for a, b in ((sh + 0.3 * (el - sh), el), (el, wr), (wr, wr + 0.5 * (wr - el))):
            ab = b - a
            s = np.clip((world - a) @ ab / max(float(ab @ ab), 1e-9), 0.0, 1.0)
            gone |= np.linalg.norm(world - (a + s[:, None] * ab), axis=-1) < ARM_RADIUS_M
    depth[v[gone], u[gone]] = 0
    return DepthFrame(t_ns=frame.t_ns, sensor=frame.sensor, camera_to_world=frame.camera_to_world,
                      depth_mm=depth, intrinsics=frame.intrinsics)


def write_case(case: Case, path: Path) -> None:
    """The case's session: depth (blanked where the limb is lost), ground truth, suit."""
    motion = trim_bind_pose(load_motion(assets.bvh_dir() / case.clip))
    body = load_body(case.body)
    scene = SyntheticScene.build(motion, body, placement=case.placement(), seed=case.seed)
    suit = ImuStreamer(scene, protocol="xbus", seed=case.seed, calib_pose_error_deg=POSE_ERROR_DEG)
    streams = [scene.depth_stream(), scene.truth_stream({"body": body.name, "motion": case.clip}), suit.stream_info()]
    fps = float(scene.motion.fps)
    with SessionWriter(path, streams, start_wall_time_ns=SYNTH_WALL_TIME_NS) as writer:
        writer.attach("body.npz", body_npz_bytes(body), create_time_ns=SYNTH_WALL_TIME_NS)
        for i in range(scene.num_frames):
            t_ns = T0_NS + frame_offset_ns(i, fps)
            for packet in suit.packets_until(i, t_ns):
                writer.write(packet)
            writer.write(scene.truth(i, t_ns))
            frame = scene.depth(i, t_ns)
            if case.lost(i / fps):
                frame = blank_limb(frame, scene.joints[i], case.loss)
            writer.write(frame)


class _Collector:
    """Pipeline stage after the skeleton stage: keeps decoded suit packets and each frame's
    depth skeleton and truth."""

    name = "collect"

    def __init__(self):
        self.packets: list[MocapPacket] = []
        self.frames: list[tuple] = []

    def observe(self, frame: object) -> None:
        if isinstance(frame, MocapPacket) and frame.decoded and frame.quats is not None:
            self.packets.append(frame)

    def process(self, result: FrameResult) -> bool:
        sk, truth, depth = result.skeleton, result.truth, result.depth
        nan = np.full((NUM_JOINTS, 3), np.nan)
        self.frames.append((result.t_ns, nan if sk is None else np.asarray(sk.joints, np.float64),
                            np.zeros(NUM_JOINTS) if sk is None else np.asarray(sk.confidence, np.float64),
                            nan if truth is None else np.asarray(truth.joints, np.float64),
                            None if truth is None else truth, depth))
        return True


def run_depth_stage(case: Case, session: Path) -> CaseData:
    from live.core.heading import yaw_of
    from models.skeleton.runtime import SkeletonStage

    col = _Collector()
    Pipeline([ReplaySource(session)], [SkeletonStage(), col], mode="every").run(threading.Event())
    meta = next(s.meta for s in SessionReader(session).info.streams if s.kind == "serial")
    first: GroundTruth = next(f[4] for f in col.frames if f[4] is not None)
    fps = float(next(s.meta for s in SessionReader(session).info.streams if s.kind == "depth")["fps"])
    t = np.array([f[0] for f in col.frames], np.int64)
    return CaseData(case=case, packet_t=np.array([p.t_ns for p in col.packets], np.int64),
                    packet_count=np.array([len(p.sensors) for p in col.packets], np.int64),
                    sensors=np.concatenate([p.sensors for p in col.packets]).astype(np.int64),
                    quats=np.concatenate([p.quats for p in col.packets]).astype(np.float64),
                    t=t, depth=np.stack([f[1] for f in col.frames]), conf=np.stack([f[2] for f in col.frames]),
                    truth=np.stack([f[3] for f in col.frames]),
                    lost=np.array([case.lost(round((ti - T0_NS) * fps / 1e9) / fps) for ti in t]),
                    meta=meta, start_root=np.asarray(first.root, np.float64),
                    start_yaw=float(yaw_of(np.asarray(first.rotations[0], np.float64))),
                    depth_mm=np.stack([f[5].depth_mm for f in col.frames]),
                    intrinsics=np.asarray(col.frames[0][5].intrinsics, np.float64),
                    camera_to_world=np.stack([np.asarray(f[5].camera_to_world, np.float64) for f in col.frames]))


_ARRAYS = ("packet_t", "packet_count", "sensors", "quats", "t", "depth", "conf", "truth", "lost", "start_root",
           "depth_mm", "intrinsics", "camera_to_world")


def model_key() -> str:
    """A hash of the skeleton stage's model files (the shipped regressor and its online temporal
    model) and CACHE_VERSION: the cache folder of cases made behind them."""
    from models.skeleton.runtime import DEFAULT_MODEL
    from models.skeleton.temporal import temporal_model_path

    h = hashlib.sha1(f"v{CACHE_VERSION}".encode())
    for path in (DEFAULT_MODEL, temporal_model_path(0, DEFAULT_MODEL)):
        h.update(path.name.encode())
        h.update(path.read_bytes() if path.is_file() else b"absent")
    return h.hexdigest()[:12]


def load_case(case: Case, cache: Path | None = None) -> CaseData:
    """The case from the cache (default: the folder of the shipped model files,
    ``CACHE / model_key()``), made and run through the depth stage the first time."""
    cache = CACHE / model_key() if cache is None else cache
    path = cache / f"{case.name}.npz"
    if path.is_file():
        z = np.load(path, allow_pickle=False)
        return CaseData(case=case, meta=json.loads(str(z["meta"])), start_yaw=float(z["start_yaw"]),
                        **{k: z[k] for k in _ARRAYS})
    cache.mkdir(parents=True, exist_ok=True)
    session = cache / f"{case.name}.mcap"
    write_case(case, session)
    data = run_depth_stage(case, session)
    session.unlink()
    part = path.with_suffix(".part.npz")  # a run stopped while writing leaves no half case
    np.savez_compressed(part, meta=json.dumps(data.meta), start_yaw=data.start_yaw,
                        **{k: getattr(data, k) for k in _ARRAYS})
    part.replace(path)
    return data
