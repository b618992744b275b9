"""Sensor-to-segment calibration of an IMU suit from a held T-pose or N-pose.

A sensor s strapped to segment j reports q_s = H G_j M_s (sensor-to-world): G_j is the segment's
global rotation (canonical: identity in the T-pose facing +z), M_s the unknown mounting
(sensor in segment) and H the heading of the sensor's world frame (a yaw: IMU worlds share the
gravity axis). While the performer holds a known pose P (facing some unknown direction), every
q_s = A P_j M_s with A = H * (performer's facing), a yaw. A single static pose cannot separate
A from M_s, so A is taken from the layout's nominal mountings N_s ~ M_s (suit pockets): each
sensor votes yaw(q_s N_s^-1 P_j^-1) and the circular mean of the votes (one shared world, e.g.
magnetometer-referenced Xsens) or each vote alone (``per_sensor_heading``, suits whose sensors
have unrelated headings) is A. Then, with heading_s = A^-1 and offset_s = q_s^-1 A P_j:

    G_j(t) = heading_s * q_s(t) * offset_s          (calibration frame: performer faced +z)

which is exact for any mounting; only the heading vote depends on the nominal mounting.
"""

from __future__ import annotations

import json
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from live.core.errors import FormatError, UserInputError
from live.core.frames import MocapPacket
from live.core.heading import mean_angle, yaw_of, yaw_quat
from live.core.jsonfile import read_json
from live.core.rotations import (
    quat_angle,
    quat_between,
    quat_conjugate,
    quat_identity,
    quat_multiply,
    quat_normalize,
)
from live.core.skeleton import JOINT_INDEX, JOINT_NAMES, NUM_JOINTS, default_rest_joints
from live.imu.layout import SuitLayout, load_suit_layout

POSES = ("tpose", "npose")


def mean_quat(q: np.ndarray) -> np.ndarray:
    """Average of nearby rotations (N, 4) -> (4,): signs aligned to the first, then normalised
    (accurate for the small spreads of a held pose)."""
    q = np.asarray(q, dtype=np.float64)
    q = np.where((q @ q[0])[:, None] < 0, -q, q)
    return quat_normalize(q.mean(axis=0))


def pose_globals(pose: str, rest_joints: np.ndarray | None = None) -> np.ndarray:
    """(22, 4) global rotation of every segment in a calibration pose, facing +z.

    "tpose": identity everywhere (the canonical rest pose). "npose": standing, arms hanging
    straight down, palms facing the thighs: each arm segment (shoulder, elbow, wrist) turned so
    that its rest bone direction points straight down."""
    if pose not in POSES:
        raise UserInputError(f"unknown calibration pose {pose!r}; expected one of {POSES}")
    out = quat_identity((NUM_JOINTS,))
    if pose == "npose":
        rest = np.asarray(default_rest_joints() if rest_joints is None else rest_joints, np.float64)
        for side in ("left", "right"):
            sh, el, wr = (JOINT_INDEX[f"{side}_{n}"] for n in ("shoulder", "elbow", "wrist"))
            arm = rest[wr] - rest[sh]
            # Swing about the forward axis only (no twist): the arm drops in the frontal plane.
            down = quat_between(arm, np.array([0.0, -1.0, 0.0]))
            out[[sh, el, wr]] = down
    return out


@dataclass(frozen=True)
class Calibration:
    """Per-sensor corrections, S sensors (layout order). G_j = heading * q_s * offset.

    sensors (S,) int64; joints (S,) int64 segment joint; heading (S, 4) yaw quaternions;
    offset (S, 4) sensor-to-segment rotations; spread_deg (S,) how much each sensor moved during
    the hold (max angle from its mean); pose; rest_joints (22, 3) the performer's T-pose skeleton
    (from their height, or later from the depth skeleton); t_ns (2,) the hold window."""

    sensors: np.ndarray
    joints: np.ndarray
    heading: np.ndarray
    offset: np.ndarray
    spread_deg: np.ndarray
    pose: str
    rest_joints: np.ndarray
    t_ns: tuple[int, int] = (0, 0)

    def segment_globals(self, quats: np.ndarray) -> np.ndarray:
        """Sensor orientations (..., S, 4) in layout order -> segment global rotations (..., S, 4)
        in the calibration frame (the performer faced +z during the hold)."""
        q = np.asarray(quats, dtype=np.float64)
        return quat_normalize(quat_multiply(quat_multiply(self.heading, q), self.offset))

    def to_json(self) -> dict:
        return {"pose": self.pose, "sensors": self.sensors.tolist(),
                "segments": [JOINT_NAMES[int(j)] for j in self.joints],
                "heading": self.heading.tolist(), "offset": self.offset.tolist(),
                "spread_deg": self.spread_deg.tolist(), "rest_joints": np.asarray(self.rest_joints).tolist(),
                "t_ns": [int(v) for v in self.t_ns]}

    @classmethod
    def from_json(cls, obj: dict, path: str | None = None) -> Calibration:
        """A calibration from its JSON object, every field checked (FormatError naming the first
        that is wrong): S sensors with one known segment each, unit quaternions, finite numbers."""
        if not isinstance(obj, dict):
            raise FormatError(f"not a calibration file (a JSON object, not {type(obj).__name__})", path=path)
        try:
            S = len(obj["sensors"])
            if not isinstance(obj["sensors"], list) or len(obj["segments"]) != S:
                raise ValueError("sensors and segments must be lists of the same length")
            sensors = np.asarray(obj["sensors"])
            if S and (sensors.dtype.kind not in "iu" or sensors.min() < 0 or sensors.max() > np.iinfo(np.int64).max):
                raise ValueError("sensor ids must be non-negative integers")
            cal = cls(sensors=sensors.astype(np.int64),
                      joints=np.array([JOINT_INDEX[str(n)] for n in obj["segments"]], np.int64),
                      heading=_finite(obj["heading"], (S, 4), "heading"),
                      offset=_finite(obj["offset"], (S, 4), "offset"),
                      spread_deg=_finite(obj.get("spread_deg", [0.0] * S), (S,), "spread_deg"),
                      pose=str(obj["pose"]), rest_joints=_finite(obj["rest_joints"], (NUM_JOINTS, 3), "rest_joints"),
                      t_ns=tuple(int(v) for v in obj.get("t_ns", (0, 0))))
            for key in ("heading", "offset"):
                norms = np.linalg.norm(getattr(cal, key), axis=-1)
                if S and np.abs(norms - 1.0).max() > 1e-3:
                    raise ValueError(f"{key} must hold unit quaternions (norms {norms.min():.3g}..{norms.max():.3g})")
            if cal.pose not in POSES:
                raise ValueError(f"pose must be one of {POSES}")
        except (KeyError, ValueError, TypeError, OverflowError) as e:
            raise FormatError(f"not a calibration file ({type(e).__name__}: {e})", path=path) from None
        return cal

    def save(self, path: str | Path) -> Path:
        p = Path(path)
        p.write_text(json.dumps(self.to_json(), indent=1))
        return p

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        p = Path(path)
        if not p.is_file():
            raise UserInputError(f"calibration file not found: {p}")
        return cls.from_json(read_json(p), path=str(p))


def _finite(value, shape: tuple[int, ...], key: str) -> np.ndarray:
    """A float64 array of the given shape with finite values (ValueError otherwise)."""
    a = np.asarray(value, dtype=np.float64)
    if a.shape != shape:
        raise ValueError(f"{key} must have shape {shape}, not {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{key} holds NaN or infinite values")
    return a


def collect_samples(packets: Iterable[MocapPacket], layout: SuitLayout) -> dict[int, list]:
    """Decoded packets -> {layout row: [(t_ns, quat (4,)), ...]} (unknown sensors and records
    without an orientation are skipped)."""
    rows = layout.index_of()
    out: dict[int, list] = {i: [] for i in range(layout.size)}
    for p in packets:
        if p.sensors is None or p.quats is None:
            continue
        for s, q in zip(np.asarray(p.sensors).tolist(), np.asarray(p.quats, np.float64)):
            i = rows.get(int(s))
            if i is not None and np.all(np.isfinite(q)):
                out[i].append((p.t_ns, q))
    return out


def calibrate(packets: Iterable[MocapPacket], layout: SuitLayout | str | Path | dict | None = None,
              pose: str = "tpose", rest_joints: np.ndarray | None = None, *,
              per_sensor_heading: bool = False, max_spread_deg: float = 10.0) -> Calibration:
    """Decoded packets recorded while the performer held ``pose`` -> Calibration.

    layout: a SuitLayout or anything ``load_suit_layout`` takes; rest_joints: (22, 3) the
    performer's T-pose (default: a 1.75 m adult). Raises UserInputError when a sensor of the
    layout sent nothing or moved more than ``max_spread_deg`` during the hold."""
    layout = load_suit_layout(layout)
    rest = np.asarray(default_rest_joints() if rest_joints is None else rest_joints, np.float64)
    samples = collect_samples(packets, layout)
    silent = [int(layout.sensors[i]) for i, v in samples.items() if not v]
    if silent:
        raise UserInputError(f"calibration: no samples from sensor(s) {silent}; check the suit and layout")
    P = pose_globals(pose, rest)[layout.joints]
    mean = np.stack([mean_quat(np.stack([q for _, q in samples[i]])) for i in range(layout.size)])
    spread = np.array([np.degrees(quat_angle(quat_multiply(quat_conjugate(mean[i]),
                                                           np.stack([q for _, q in samples[i]]))).max())
                       for i in range(layout.size)])
    moved = np.flatnonzero(spread > max_spread_deg)
    if len(moved):
        i = int(moved[0])
        raise UserInputError(f"calibration: sensor {int(layout.sensors[i])} ({JOINT_NAMES[int(layout.joints[i])]}) "
                             f"moved {spread[i]:.0f} deg during the hold; hold the {pose} still")
    votes = yaw_of(quat_multiply(quat_multiply(mean, quat_conjugate(layout.mounting)), quat_conjugate(P)))
    if per_sensor_heading:
        yaw = votes
    else:
        yaw = np.full(layout.size, mean_angle(votes))
    A = yaw_quat(yaw)
    offset = quat_normalize(quat_multiply(quat_multiply(quat_conjugate(mean), A), P))
    times = [t for v in samples.values() for t, _ in v]
    return Calibration(sensors=layout.sensors.copy(), joints=layout.joints.copy(), heading=quat_conjugate(A),
                       offset=offset, spread_deg=spread, pose=pose, rest_joints=rest,
                       t_ns=(int(min(times)), int(max(times))))


class CalibrationCollector:
    """Finds the held pose in a live stream (the countdown of ``livecap run`` / ``calibrate``).

    ``feed(packet)`` returns a Calibration once every sensor of the layout has stayed within
    ``still_deg`` of its first sample for ``hold_s`` seconds, or, when the performer starts
    moving, if the still stretch lasted at least ``min_hold_s`` (its last ``trim_s`` seconds,
    where the movement was starting, are left out)."""

    def __init__(self, layout: SuitLayout, pose: str = "tpose", rest_joints: np.ndarray | None = None, *,
                 hold_s: float = 2.0, min_hold_s: float | None = None, still_deg: float = 5.0,
                 trim_s: float = 0.15, per_sensor_heading: bool = False):
        self.layout = layout
        self.pose = pose
        self.rest_joints = rest_joints
        self.hold_ns = int(hold_s * 1e9)
        self.min_hold_ns = int((hold_s if min_hold_s is None else min_hold_s) * 1e9)
        self.still_cos = np.cos(np.radians(still_deg) / 2)
        self.trim_ns = int(trim_s * 1e9)
        self.per_sensor_heading = per_sensor_heading
        self._rows = layout.index_of()
        self._window: deque[MocapPacket] = deque()
        self._ref = np.full((layout.size, 4), np.nan)
        self.attempts = 0

    def _restart(self, packet: MocapPacket | None) -> None:
        self._window.clear()
        self._ref[:] = np.nan
        if packet is not None:
            self._add(packet)

    def _add(self, packet: MocapPacket) -> None:
        self._window.append(packet)
        for s, q in zip(packet.sensors.tolist(), np.asarray(packet.quats, np.float64)):
            i = self._rows.get(int(s))
            if i is not None and np.isnan(self._ref[i, 0]) and np.all(np.isfinite(q)):
                self._ref[i] = q

    def _moved(self, packet: MocapPacket) -> bool:
        for s, q in zip(packet.sensors.tolist(), np.asarray(packet.quats, np.float64)):
            i = self._rows.get(int(s))
            if i is not None and not np.isnan(self._ref[i, 0]) and abs(float(self._ref[i] @ q)) < self.still_cos:
                return True
        return False

    def _span(self) -> int:
        return self._window[-1].t_ns - self._window[0].t_ns if self._window else 0

    def _try(self, end_ns: int) -> Calibration | None:
        if np.isnan(self._ref[:, 0]).any() or self._span() < self.min_hold_ns - self.trim_ns:
            return None
        packets = [p for p in self._window if p.t_ns <= end_ns]
        self.attempts += 1
        try:
            return calibrate(packets, self.layout, self.pose, self.rest_joints,
                             per_sensor_heading=self.per_sensor_heading)
        except UserInputError:
            return None

    def feed(self, packet: MocapPacket) -> Calibration | None:
        if packet.sensors is None or packet.quats is None or len(packet.sensors) == 0:
            return None
        if self._window and self._moved(packet):
            last = self._window[-1].t_ns
            cal = None
            if self._span() >= self.min_hold_ns:
                cal = self._try(last - self.trim_ns)
            self._restart(packet)
            return cal
        self._add(packet)
        if self._span() >= self.hold_ns:
            cal = self._try(self._window[-1].t_ns)
            if cal is not None:
                return cal
            self._restart(None)
        return None
