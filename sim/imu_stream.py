"""The simulated IMU suit inside synthetic sessions (``livecap synth --imu xbus|lines``).

``ImuStreamer(scene, protocol, seed)`` turns the scene's motion into the bytes a serial suit
would deliver, as ``MocapPacket(t_ns, device, raw=...)`` reads between camera frames. The
performer first holds a calibration pose (T-pose by default) facing the way the clip starts,
for as long as fits before the first camera frame (up to ``calib_hold_s``), then blends into
the clip. Sensors sit on the segments of the suit layout with their nominal pocket orientation
plus a random mounting error, their orientation carries jitter and a slow per-sensor heading
drift, their gyro noise and bias (sim.imu_model). Reads arrive ``latency_ms`` after the sample
plus the time the bytes take on the wire; some samples are split across two reads. Same scene,
protocol and seed -> same bytes. ``sent`` keeps every record for tests.

``NoisySkeletonStage`` stands in for the depth skeleton regressor in tests and evaluations:
ground-truth joints plus noise, a fixed per-joint bias and occlusion spells with low confidence.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from drivers import xbus
from drivers.text_lines import encode_line
from live.core.frames import FrameResult, MocapPacket, SkeletonFrame
from live.core.heading import yaw_of, yaw_quat
from live.core.kinematics import local_rotations
from live.core.protocols import StreamInfo
from live.core.rotations import quat_from_axis_angle, quat_multiply, quat_normalize, quat_slerp
from live.core.skeleton import JOINT_INDEX, NUM_JOINTS
from live.core.timing import frame_offset_ns, seconds_between
from live.imu.calibration import pose_globals
from live.imu.layout import SuitLayout, load_suit_layout
from sim.imu_model import ImuNoise, ImuTrack, SimpleMotion, simulate_imus

PROTOCOLS = ("xbus", "lines")
#: Typical MEMS suit in an indoor room: ~0.3 deg orientation jitter, heading drift rates of
#: ~0.1 deg/s (6 deg/min, magnetically disturbed rooms), gyro noise and bias of a few mrad/s.
DEFAULT_NOISE = ImuNoise(gyro_std=0.005, gyro_bias_std=0.002, acc_std=0.05, mag_std=0.01,
                         orient_std=float(np.radians(0.3)), yaw_drift_std=float(np.radians(0.1)))
#: Time kept free before the first camera frame of a session (the writer starts at 0 ns).
_MARGIN_S = 0.05
_FIRST_FRAME_S = 1.0  # sim.synth.T0_NS


@dataclass(frozen=True)
class SentRecord:
    """One record the suit sent (handed out by packets_until): step, sensor id, counter as
    decoded, the world quaternion given to the encoder, and the arrival time of the read that
    completed it."""

    step: int
    sensor: int
    counter: int
    quat: tuple[float, float, float, float]
    t_ns: int


def mounting_rotations(layout: SuitLayout, error_deg: float, rng: np.random.Generator) -> np.ndarray:
    """(S, 4) actual sensor-in-segment rotations: the layout's nominal pocket orientation times
    a random error (rotation vector with per-axis std ``error_deg``)."""
    err = quat_from_axis_angle(rng.normal(0.0, np.radians(error_deg), (layout.size, 3)))
    return quat_normalize(quat_multiply(layout.mounting, err))


def sample_motion(rotations: np.ndarray, root: np.ndarray, fps: float, times: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Motion (T, 22, 4) / (T, 3) at ``fps`` sampled at times (K,) seconds (clamped to the
    clip): rotations slerped, root linear."""
    T = len(root)
    pos = np.clip(np.asarray(times) * fps, 0, T - 1)
    i0 = np.minimum(np.floor(pos).astype(np.int64), T - 1)
    i1 = np.minimum(i0 + 1, T - 1)
    w = pos - i0
    rot = quat_slerp(rotations[i0].astype(np.float64), rotations[i1].astype(np.float64), w[:, None, None])
    r = (1 - w)[:, None] * root[i0] + w[:, None] * root[i1]
    return rot, r


def calibration_prelude(first_rotations: np.ndarray, pose: str, rest_joints: np.ndarray, hold_s: float,
                        blend_s: float, rate_hz: float, pose_error: np.ndarray | None = None) -> np.ndarray:
    """(K, 22, 4) local rotations: ``pose`` held for hold_s facing the clip's first heading,
    then a smooth blend into ``first_rotations`` (22, 4) over blend_s; K samples at rate_hz.
    pose_error (22, 4): how the performer's held pose differs from the ideal one (each segment
    turned by it in its own frame; None: held exactly)."""
    facing = yaw_quat(yaw_of(first_rotations[0]))
    held = quat_multiply(facing, pose_globals(pose, rest_joints))
    if pose_error is not None:
        held = quat_normalize(quat_multiply(held, pose_error))
    calib = local_rotations(held)
    n = int(round((hold_s + blend_s) * rate_hz))
    t = np.arange(n) / rate_hz
    x = np.clip((t - hold_s) / max(blend_s, 1e-9), 0.0, 1.0)
    w = x * x * (3 - 2 * x)  # smoothstep: starts and ends at rest
    return quat_slerp(np.broadcast_to(calib, (n, NUM_JOINTS, 4)),
                      np.broadcast_to(first_rotations, (n, NUM_JOINTS, 4)), w[:, None, None])


class ImuStreamer:
    """Serial bytes of a simulated suit for a SyntheticScene (see module doc).

    protocol: "xbus" (MTData2: counter, SampleTimeFine, quaternion, acceleration, rate of turn,
    float32, one bus id per sensor) or "lines" (CSV with acc and gyro, checksummed)."""

    def __init__(self, scene, protocol: str = "xbus", seed: int = 0, *, rate_hz: float = 100.0,
                 layout=None, device: str = "suit", mounting_error_deg: float = 10.0,
                 noise: ImuNoise = DEFAULT_NOISE, calib_pose: str = "tpose", calib_hold_s: float = 2.0,
                 blend_s: float = 0.25, latency_ms: float = 1.0, baud: int = 2_000_000,
                 split_prob: float = 0.3, calib_pose_error_deg: float = 0.0):
        if protocol not in PROTOCOLS:
            raise ValueError(f"unknown protocol {protocol!r}; expected one of {PROTOCOLS}")
        self.scene = scene
        self.protocol = protocol
        self.seed = int(seed)
        self.rate_hz = float(rate_hz)
        self.layout = load_suit_layout(layout)
        self.device = device
        self.noise = noise
        self.calib_pose = calib_pose
        self.blend_s = float(blend_s)
        self.hold_s = float(min(calib_hold_s, _FIRST_FRAME_S - _MARGIN_S - self.blend_s))
        self.latency_ns = int(latency_ms * 1e6)
        self.baud = int(baud)
        self.split_prob = float(split_prob)
        rng = np.random.default_rng([self.seed, 0x1A0])
        self.mounting = mounting_rotations(self.layout, mounting_error_deg, rng)
        self.pose_error = None
        if calib_pose_error_deg > 0:
            err = np.random.default_rng([self.seed, 0x1A2]).normal(0.0, np.radians(calib_pose_error_deg), (NUM_JOINTS, 3))
            err[0, 1] = 0.0  # where the performer faces is not an error of the pose
            self.pose_error = quat_from_axis_angle(err)
        self._rng = np.random.default_rng([self.seed, 0x1A1])
        self.track: ImuTrack | None = None
        self.sent: list[SentRecord] = []
        self._queue: deque[tuple[MocapPacket, list[SentRecord]]] = deque()
        self._step = 0
        self._t0_ns = 0  # session time of IMU step 0
        self._last_arrival = -1

    def stream_info(self) -> StreamInfo:
        return StreamInfo(self.device, "serial", {
            "protocol": self.protocol, "layout": self.layout.to_json(), "rate_hz": self.rate_hz,
            "baud": self.baud, "simulated": True,
            "calibration": {"pose": self.calib_pose, "hold_s": round(self.hold_s, 4)}})

    def _start(self, frame: int, t_ns: int) -> None:
        """Simulate the whole suit track once the first frame (index, time) is known."""
        scene = self.scene
        fps = float(scene.motion.fps)
        hold = min(self.hold_s, t_ns / 1e9 - _MARGIN_S - self.blend_s)
        if hold < 0.1:
            raise ValueError("the first camera frame comes too early for the calibration pose")
        self.hold_s = hold
        rest = np.asarray(scene.body.rest_joints, np.float64)
        rot = np.asarray(scene.motion.rotations, np.float64)
        root = np.asarray(scene.root, np.float64)
        start_s = frame / fps
        n_clip = int(np.floor((len(root) - 1 - frame) / fps * self.rate_hz)) + 1
        clip_rot, clip_root = sample_motion(rot, root, fps, start_s + np.arange(n_clip) / self.rate_hz)
        pre = calibration_prelude(clip_rot[0], self.calib_pose, rest, hold, self.blend_s, self.rate_hz,
                                  self.pose_error)
        pre_root = np.broadcast_to(clip_root[0], (len(pre), 3))
        motion = SimpleMotion(fps=self.rate_hz, rotations=np.concatenate([pre, clip_rot]),
                              root=np.concatenate([pre_root, clip_root]), rest_joints=rest)
        self.track = simulate_imus(motion, self.layout.as_dict(), mounting=self.mounting, noise=self.noise,
                                   seed=self.seed)
        self._t0_ns = t_ns - frame_offset_ns(len(pre), self.rate_hz)

    def sample_time_ns(self, step: int) -> int:
        return self._t0_ns + frame_offset_ns(step, self.rate_hz)

    def _encode(self, step: int) -> tuple[bytes, list[tuple[int, int, int, tuple]]]:
        """Bytes of one sample of every sensor, and (end offset, sensor, counter, quat) each."""
        tr = self.track
        out = bytearray()
        rows = []
        t_s = seconds_between(self._t0_ns, self.sample_time_ns(step))
        for s, sensor in enumerate(tr.sensors.tolist()):
            q = tuple(float(v) for v in tr.quats[step, s])
            acc, gyro = tr.acc[step, s], tr.gyro[step, s]
            if self.protocol == "xbus":
                payload = xbus.encode_mtdata2(quat=q, counter=step, sample_time_fine=int(round(t_s * 10000)),
                                              acc=acc, gyro=gyro)
                out += xbus.encode_message(sensor, xbus.MID_MTDATA2, payload)
                counter = step & 0xFFFF
            else:
                counter = int(round(t_s * 1e6))
                out += encode_line(sensor, counter, q, acc=acc, gyro=gyro, checksum=True)
            rows.append((len(out), int(sensor), counter, q))
        return bytes(out), rows

    def _produce(self) -> bool:
        """Queue the reads of the next sample; False at the end of the clip."""
        if self._step >= self.track.frames:
            return False
        step = self._step
        data, rows = self._encode(step)
        wire_ns = len(data) * 10 * 1e9 / self.baud  # 8N1: ten bits per byte
        t = self.sample_time_ns(step) + self.latency_ns
        cuts = [len(data)]
        if self._rng.random() < self.split_prob:
            cuts = [int(self._rng.integers(1, len(data))), len(data)]
        begin = 0
        for cut in cuts:
            arrival = max(t + int(wire_ns * cut / len(data)), self._last_arrival + 1)
            self._last_arrival = arrival
            done = [SentRecord(step, sensor, counter, q, arrival) for end, sensor, counter, q in rows
                    if begin < end <= cut]
            self._queue.append((MocapPacket(t_ns=arrival, device=self.device, raw=data[begin:cut]), done))
            begin = cut
        self._step += 1
        return True

    def packets_until(self, frame: int, t_ns: int) -> Iterator[MocapPacket]:
        """Every read that arrived at or before ``t_ns`` (camera frame ``frame``'s time) and was
        not handed out yet, in arrival order."""
        if self.track is None:
            self._start(frame, t_ns)
        while True:
            while not self._queue:
                if not self._produce():
                    return
            if self._queue[0][0].t_ns > t_ns:
                return
            packet, done = self._queue.popleft()
            self.sent.extend(done)
            yield packet


class NoisySkeletonStage:
    """Pipeline stage ``skeleton`` for evaluations without a trained regressor: the ground-truth
    joints plus white noise (``noise_m`` per axis), a fixed per-joint bias (``bias_m``), and
    occlusion spells (on average every ``occlusion_every_s``, lasting ``occlusion_s``) during
    which one limb is off by ~``occlusion_m`` with confidence 0.1. Deterministic for a seed."""

    name = "skeleton"
    _LIMBS = tuple(tuple(JOINT_INDEX[f"{side}_{j}"] for j in joints)
                   for side in ("left", "right")
                   for joints in (("elbow", "wrist"), ("knee", "ankle", "foot")))

    def __init__(self, noise_m: float = 0.02, bias_m: float = 0.015, occlusion_every_s: float = 4.0,
                 occlusion_s: float = 0.8, occlusion_m: float = 0.15, seed: int = 0):
        self.rng = np.random.default_rng([seed, 0x5CE])
        self.noise_m, self.occlusion_m = noise_m, occlusion_m
        self.bias = self.rng.normal(0.0, bias_m, (NUM_JOINTS, 3))
        self.rate = 1.0 / occlusion_every_s if occlusion_every_s > 0 else 0.0
        self.occlusion_ns = int(occlusion_s * 1e9)
        self._occ: tuple[int, tuple[int, ...], np.ndarray] | None = None
        self._last_t: int | None = None

    def observe(self, frame: object) -> None:
        pass

    def process(self, result: FrameResult) -> bool:
        if result.truth is None or result.depth is None:
            return False
        t = result.t_ns
        dt = 0.0 if self._last_t is None else seconds_between(self._last_t, t)
        self._last_t = t
        joints = np.asarray(result.truth.joints, np.float64) + self.bias
        joints = joints + self.rng.normal(0.0, self.noise_m, joints.shape)
        conf = np.ones(NUM_JOINTS)
        if self._occ is not None and t > self._occ[0]:
            self._occ = None
        if self._occ is None and self.rng.random() < self.rate * dt:
            limb = self._LIMBS[int(self.rng.integers(len(self._LIMBS)))]
            self._occ = (t + self.occlusion_ns, limb, self.rng.normal(0.0, self.occlusion_m, 3))
        if self._occ is not None:
            _, limb, off = self._occ
            joints[list(limb)] += off
            conf[list(limb)] = 0.1
        result.skeleton = SkeletonFrame(t_ns=t, joints=joints.astype(np.float32), confidence=conf.astype(np.float32))
        return True


@dataclass
class _RestBody:
    rest_joints: np.ndarray
    name: str = "rest"


@dataclass
class MotionScene:
    """The parts of sim.synth.SyntheticScene the suit needs, without a camera or a mesh: a motion
    (``.rotations (T,22,4)``, ``.fps``) performed on a rest skeleton. root (T, 3) is the motion's
    root scaled by the leg-length ratio, joints (T, 22, 3) the ground truth."""

    motion: object
    body: object
    root: np.ndarray
    joints: np.ndarray

    @classmethod
    def of(cls, motion, rest_joints: np.ndarray | None = None) -> MotionScene:
        from live.core.kinematics import forward_kinematics
        from live.core.skeleton import pelvis_height

        rest = np.asarray(motion.rest_joints if rest_joints is None else rest_joints, np.float64)
        ratio = pelvis_height(rest) / max(pelvis_height(motion.rest_joints), 1e-6)
        root = np.asarray(motion.root, np.float64) * ratio
        joints, _ = forward_kinematics(motion.rotations, root, rest)
        return cls(motion=motion, body=_RestBody(rest), root=root, joints=joints)

    @property
    def num_frames(self) -> int:
        return len(self.root)


def write_suit_session(path, scene, *, protocol: str = "xbus", seed: int = 0, frames: int | None = None,
                       fps: float | None = None, depth: bool = True, **streamer_options) -> ImuStreamer:
    """A session like ``livecap synth --imu`` writes, for scenes without a renderer: the suit's
    serial stream, ground truth, and (``depth=True``) a stand-in depth stream whose clouds are
    the ground-truth joints (camera = world). Frame k is at sim.synth's T0 + k / fps."""
    from live.core.frames import DepthFrame
    from live.io.session import SessionWriter

    fps = float(fps or scene.motion.fps)
    t0 = int(_FIRST_FRAME_S * 1e9)
    n = scene.num_frames if frames is None else min(frames, scene.num_frames)
    suit = ImuStreamer(scene, protocol=protocol, seed=seed, **streamer_options)
    streams = [StreamInfo("gt", "gt", {"body": getattr(scene.body, "name", "rest")}), suit.stream_info()]
    if depth:
        streams.insert(0, StreamInfo("cam", "depth", {"camera_to_world": np.eye(4).tolist(), "fps": fps,
                                                      "stand_in": "ground-truth joints"}))
    from live.core.frames import GroundTruth

    with SessionWriter(path, streams, start_wall_time_ns=0) as writer:
        for k in range(n):
            t_ns = t0 + frame_offset_ns(k, fps)
            for packet in suit.packets_until(k, t_ns):
                writer.write(packet)
            joints = np.asarray(scene.joints[k], np.float32)
            writer.write(GroundTruth(t_ns=t_ns, joints=joints, rotations=np.asarray(scene.motion.rotations[k], np.float32),
                                     root=np.asarray(scene.root[k], np.float32)))
            if depth:
                writer.write(DepthFrame(t_ns=t_ns, sensor="cam", points=joints))
    return suit
