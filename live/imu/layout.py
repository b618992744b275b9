"""Suit layouts: which segment each IMU sensor id is strapped to (the one layout parser).

A layout file is JSON ``{"name": ..., "sensors": {"<id>": "<segment>", ...}}`` (optional
"description"), a segment being a canonical joint name (``left_elbow`` = the left forearm, the
segment that joint's global rotation moves) or one of SEGMENT_ALIASES (``chest``,
``left_forearm``, ...). Partial suits simply list fewer sensors. The shipped layouts are in
drivers/layouts (``full_body.json``: 15 sensors).

One optional key: ``"mounting": {"<id>": [w, x, y, z]}``, the nominal sensor-in-segment rotation
of each pocket (identity when absent: the sensor's axes line up with the segment's axes in the
canonical T-pose). Calibration only needs it to find the performer's heading from a single
static pose; the exact mounting comes out of the calibration itself.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from live.core import assets
from live.core.errors import FormatError
from live.core.rotations import quat_normalize
from live.core.skeleton import JOINT_INDEX, JOINT_NAMES

DEFAULT_LAYOUT = assets.layouts_dir() / "full_body.json"
_INT64 = np.iinfo(np.int64)

#: Segment names people use for suits -> canonical joint.
SEGMENT_ALIASES: dict[str, str] = {
    "chest": "spine3", "sternum": "spine3",
    "left_upper_arm": "left_shoulder", "right_upper_arm": "right_shoulder",
    "left_forearm": "left_elbow", "right_forearm": "right_elbow",
    "left_hand": "left_wrist", "right_hand": "right_wrist",
    "left_thigh": "left_hip", "right_thigh": "right_hip",
    "left_shin": "left_knee", "right_shin": "right_knee",
    "left_foot_segment": "left_ankle", "right_foot_segment": "right_ankle",
}


#: Segment words of suit vendors and recording software (MVN's segment labels, x-IMU3 device
#: names, Xsens DOT tags) -> the canonical joint whose global rotation the segment follows,
#: without the side. "shoulder" is the vendors' (MVN's) clavicle segment, not the canonical
#: shoulder joint (the upper arm); "foot" is the foot segment (canonical ankle), "toe" the toes.
LABEL_PARTS: dict[str, str] = {
    "pelvis": "pelvis", "hips": "pelvis", "hip": "hip", "sacrum": "pelvis", "waist": "pelvis",
    "l5": "spine1", "lumbar": "spine1", "lowerback": "spine1", "abdomen": "spine1", "spine1": "spine1",
    "l3": "spine2", "spine": "spine2", "spine2": "spine2",
    "t8": "spine3", "chest": "spine3", "sternum": "spine3", "thorax": "spine3", "upperback": "spine3",
    "trunk": "spine3", "torso": "spine3", "spine3": "spine3",
    "neck": "neck", "head": "head",
    "shoulder": "collar", "clavicle": "collar", "collar": "collar",
    "upperarm": "shoulder", "humerus": "shoulder", "arm": "shoulder",
    "forearm": "elbow", "lowerarm": "elbow", "radius": "elbow", "elbow": "elbow",
    "hand": "wrist", "wrist": "wrist",
    "upperleg": "hip", "thigh": "hip", "femur": "hip", "upleg": "hip",
    "lowerleg": "knee", "shank": "knee", "shin": "knee", "tibia": "knee", "leg": "knee", "calf": "knee",
    "knee": "knee",
    "foot": "ankle", "ankle": "ankle", "toe": "foot", "toes": "foot", "toebase": "foot",
}
_SIDES = (("left", "left"), ("right", "right"), ("l", "left"), ("r", "right"))


def segment_from_label(label: str) -> int | None:
    """A recording's segment label (``Pelvis``, ``LeftUpperLeg``, ``left_lower_leg``, ``LFemur``,
    ``Right Foot``, ``T8``) -> canonical joint index, or None when the label names no segment
    of the 22-joint skeleton (``T12``, a device nickname). Case, spaces, ``_`` and ``-`` do not
    matter; a left/right (or L/R) prefix or suffix gives the side."""
    word = "".join(ch for ch in label.lower() if ch.isalnum())
    if word in LABEL_PARTS and LABEL_PARTS[word] in JOINT_INDEX:
        return JOINT_INDEX[LABEL_PARTS[word]]
    for affix, side in _SIDES:
        for rest in ((word[len(affix):] if word.startswith(affix) else None),
                     (word[:-len(affix)] if word.endswith(affix) and len(affix) > 1 else None)):
            part = LABEL_PARTS.get(rest) if rest else None
            if part is not None and f"{side}_{part}" in JOINT_INDEX:
                return JOINT_INDEX[f"{side}_{part}"]
    return None


@dataclass(frozen=True)
class SuitLayout:
    """A suit: S sensors. sensors (S,) int64 ids, ascending; joints (S,) int64 canonical joint
    (segment) of each; mounting (S, 4) nominal sensor-in-segment quaternions (w, x, y, z)."""

    name: str
    sensors: np.ndarray
    joints: np.ndarray
    mounting: np.ndarray

    def __post_init__(self) -> None:
        if len(set(self.joints.tolist())) != len(self.joints):
            raise FormatError(f"layout {self.name!r}: two sensors on one segment")

    @property
    def size(self) -> int:
        return int(len(self.sensors))

    def index_of(self) -> dict[int, int]:
        """{sensor id: row in the layout arrays}."""
        return {int(s): i for i, s in enumerate(self.sensors)}

    def as_dict(self) -> dict[int, int]:
        """{sensor id: joint index}, the form sim.imu_model uses."""
        return {int(s): int(j) for s, j in zip(self.sensors, self.joints)}

    def to_json(self) -> dict:
        """The layout-file object (round-trips through ``parse_suit_layout``)."""
        obj: dict = {"name": self.name,
                     "sensors": {str(int(s)): JOINT_NAMES[int(j)] for s, j in zip(self.sensors, self.joints)}}
        ident = np.allclose(self.mounting, [1.0, 0.0, 0.0, 0.0])
        if not ident:
            obj["mounting"] = {str(int(s)): [float(v) for v in q] for s, q in zip(self.sensors, self.mounting)}
        return obj


def _sensor_joints(obj: object, path: str | None) -> dict[int, int]:
    """The "sensors" of a layout object -> {sensor id: joint index}, in ascending sensor id order."""
    if not isinstance(obj, dict) or not isinstance(obj.get("sensors"), dict) or not obj["sensors"]:
        raise FormatError('a layout is {"sensors": {"<id>": "<segment>", ...}}', path=path)
    out: dict[int, int] = {}
    for key, segment in obj["sensors"].items():
        try:
            sensor = int(key)
        except ValueError:
            raise FormatError(f"sensor id {key!r} is not an integer", path=path) from None
        if not _INT64.min <= sensor <= _INT64.max:
            raise FormatError(f"sensor id {key} does not fit in 64 bits", path=path)
        name = SEGMENT_ALIASES.get(segment, segment) if isinstance(segment, str) else None
        if name not in JOINT_INDEX:
            raise FormatError(f"sensor {sensor}: unknown segment {segment!r}", path=path)
        out[sensor] = JOINT_INDEX[name]
    return dict(sorted(out.items()))


def parse_suit_layout(obj: object, *, path: str | None = None) -> SuitLayout:
    """A layout object (as in a layout file) -> SuitLayout."""
    mapping = _sensor_joints(obj, path)
    sensors = np.array(list(mapping), dtype=np.int64)
    joints = np.array([mapping[s] for s in mapping], dtype=np.int64)
    mounting = np.zeros((len(sensors), 4))
    mounting[:, 0] = 1.0
    raw = obj.get("mounting", {}) if isinstance(obj, dict) else {}
    if not isinstance(raw, dict):
        raise FormatError('"mounting" is {"<id>": [w, x, y, z], ...}', path=path)
    row = {int(s): i for i, s in enumerate(sensors)}
    for key, q in raw.items():
        try:
            i = row[int(key)]
            q = np.asarray(q, dtype=np.float64)
        except (KeyError, ValueError, TypeError):
            raise FormatError(f"mounting for unknown sensor {key!r}", path=path) from None
        if q.shape != (4,) or not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-6:
            raise FormatError(f"mounting of sensor {key} is not a quaternion (w, x, y, z)", path=path)
        mounting[i] = quat_normalize(q)
    name = obj.get("name", "suit") if isinstance(obj, dict) else "suit"
    return SuitLayout(name=str(name), sensors=sensors, joints=joints, mounting=mounting)


def load_suit_layout(spec: str | Path | dict | SuitLayout | None = None) -> SuitLayout:
    """A layout from a file path, a layout object, a SuitLayout, a {sensor id: joint index}
    dict, or None (the 15-sensor full body of drivers/layouts/full_body.json)."""
    if isinstance(spec, SuitLayout):
        return spec
    if isinstance(spec, dict):
        if spec and all(isinstance(k, int) for k in spec):  # {sensor id: joint index}
            spec = {"name": "suit", "sensors": {str(s): JOINT_NAMES[j] for s, j in spec.items()}}
        return parse_suit_layout(spec)
    from live.core.jsonfile import read_json

    p = Path(spec) if spec is not None else DEFAULT_LAYOUT
    return parse_suit_layout(read_json(p), path=str(p))
