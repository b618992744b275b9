"""Foxglove-ready sessions: a livecap session (and a replay's results) -> an MCAP file of
Foxglove's well-known schemas, so it opens in Foxglove with no plugin.

Encoding: JSON messages (``json``) with JSON Schema schemas (``jsonschema``), as Foxglove's docs
prescribe; binary fields (a point cloud's ``data``) are base64 strings marked
``contentEncoding: base64`` in the schema. The schemas are the foxglove-sdk definitions of
``foxglove.PointCloud``, ``foxglove.SceneUpdate`` and ``foxglove.FrameTransforms`` (every field
required, as upstream) without the optional provenance fields (``uuid``, ``lineage``).

Frames (FrameTransforms on ``/tf``, the whole tree in every message, one per instant):
- ``map``: Z-up root (Foxglove's views are Z-up), so the performer stands upright when it is
  the display frame;
- ``world``: livecap's world (+Y up), a fixed +90 deg rotation about X under ``map``;
- ``camera_<sensor>``: each depth camera (OpenCV axes), posed by its ``camera_to_world``.

Topics: ``/depth/<sensor>`` PointCloud (camera frame, float32 x,y,z); ``/skeleton`` (the
performer estimated by a replay, ``skeleton.npz``), ``/ground_truth`` (synthetic sessions) and
``/avatar`` (``avatar.npz``) as SceneUpdates in ``world``: a sphere per joint, one LINE_LIST for
the bones, a label. Message log_time = publish_time = the sample's t_ns (host monotonic clock).
"""

from __future__ import annotations

import base64
import heapq
import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer

from live import __version__
from live.core.errors import FormatError, UserInputError
from live.core.kinematics import forward_kinematics
from live.core.rotations import matrix_to_quat
from live.core.skeleton import BONES, JOINT_INDEX, NUM_JOINTS
from live.io.results import read_avatar, read_skeleton
from live.io.session import SessionReader

# ---------------------------------------------------------------------------------------------
# Schemas (JSON Schema), built from compact definitions so every "required" list is complete.


def _object(title: str, properties: dict, required: list[str] | None = None) -> dict:
    return {"title": title, "type": "object", "properties": properties,
            "required": list(properties) if required is None else required}


def _enum(title: str, values: dict[str, int]) -> dict:
    return {"title": title, "oneOf": [{"title": k, "const": v} for k, v in values.items()]}


def _array(items: dict) -> dict:
    return {"type": "array", "items": items}


_NUM, _STR, _BOOL = {"type": "number"}, {"type": "string"}, {"type": "boolean"}
_UINT = {"type": "integer", "minimum": 0}
_BYTES = {"type": "string", "contentEncoding": "base64"}
_NSEC = {"type": "integer", "minimum": 0, "maximum": 999_999_999}
_TIME = {"title": "time", "type": "object", "properties": {"sec": _UINT, "nsec": _NSEC},
         "required": ["sec", "nsec"]}
_DURATION = {"title": "duration", "type": "object", "properties": {"sec": {"type": "integer"}, "nsec": _NSEC},
             "required": ["sec", "nsec"]}
_VECTOR3 = _object("foxglove.Vector3", {"x": _NUM, "y": _NUM, "z": _NUM})
_POINT3 = _object("foxglove.Point3", {"x": _NUM, "y": _NUM, "z": _NUM})
_QUATERNION = _object("foxglove.Quaternion", {"x": _NUM, "y": _NUM, "z": _NUM, "w": _NUM})
_POSE = _object("foxglove.Pose", {"position": _VECTOR3, "orientation": _QUATERNION})
_COLOR = _object("foxglove.Color", {"r": _NUM, "g": _NUM, "b": _NUM, "a": _NUM})
_KEY_VALUE = _object("foxglove.KeyValuePair", {"key": _STR, "value": _STR})

NUMERIC_TYPES = {"UNKNOWN": 0, "UINT8": 1, "INT8": 2, "UINT16": 3, "INT16": 4, "UINT32": 5, "INT32": 6,
                 "FLOAT32": 7, "FLOAT64": 8}
LINE_TYPES = {"LINE_STRIP": 0, "LINE_LOOP": 1, "LINE_LIST": 2}
DELETION_TYPES = {"MATCHING_ID": 0, "ALL": 1}

_ENTITY = _object("foxglove.SceneEntity", {
    "timestamp": _TIME, "frame_id": _STR, "id": _STR, "lifetime": _DURATION, "frame_locked": _BOOL,
    "metadata": _array(_KEY_VALUE),
    "arrows": _array(_object("foxglove.ArrowPrimitive", {
        "pose": _POSE, "shaft_length": _NUM, "shaft_diameter": _NUM, "head_length": _NUM,
        "head_diameter": _NUM, "color": _COLOR})),
    "cubes": _array(_object("foxglove.CubePrimitive", {"pose": _POSE, "size": _VECTOR3, "color": _COLOR})),
    "spheres": _array(_object("foxglove.SpherePrimitive", {"pose": _POSE, "size": _VECTOR3, "color": _COLOR})),
    "cylinders": _array(_object("foxglove.CylinderPrimitive", {
        "pose": _POSE, "size": _VECTOR3, "bottom_scale": _NUM, "top_scale": _NUM, "color": _COLOR})),
    "lines": _array(_object("foxglove.LinePrimitive", {
        "type": _enum("foxglove.LineType", LINE_TYPES), "pose": _POSE, "thickness": _NUM,
        "scale_invariant": _BOOL, "points": _array(_POINT3), "color": _COLOR, "colors": _array(_COLOR),
        "indices": _array(_UINT)})),
    "triangles": _array(_object("foxglove.TriangleListPrimitive", {
        "pose": _POSE, "points": _array(_POINT3), "color": _COLOR, "colors": _array(_COLOR),
        "indices": _array(_UINT)})),
    "texts": _array(_object("foxglove.TextPrimitive", {
        "pose": _POSE, "billboard": _BOOL, "font_size": _NUM, "scale_invariant": _BOOL, "color": _COLOR,
        "text": _STR})),
    "models": _array(_object("foxglove.ModelPrimitive", {
        "pose": _POSE, "scale": _VECTOR3, "color": _COLOR, "override_color": _BOOL, "url": _STR,
        "media_type": _STR, "data": _BYTES})),
})

#: Schema name -> JSON Schema (a dict), as registered in the output file.
SCHEMAS: dict[str, dict] = {
    "foxglove.PointCloud": _object("foxglove.PointCloud", {
        "timestamp": _TIME, "frame_id": _STR, "pose": _POSE, "point_stride": _UINT,
        "fields": _array(_object("foxglove.PackedElementField", {
            "name": _STR, "offset": _UINT, "type": _enum("foxglove.NumericType", NUMERIC_TYPES)})),
        "data": _BYTES}),
    "foxglove.SceneUpdate": _object("foxglove.SceneUpdate", {
        "deletions": _array(_object("foxglove.SceneEntityDeletion", {
            "timestamp": _TIME, "type": _enum("foxglove.SceneEntityDeletionType", DELETION_TYPES), "id": _STR})),
        "entities": _array(_ENTITY)}),
    "foxglove.FrameTransforms": _object("foxglove.FrameTransforms", {
        "transforms": _array(_object("foxglove.FrameTransform", {
            "timestamp": _TIME, "parent_frame_id": _STR, "child_frame_id": _STR, "translation": _VECTOR3,
            "rotation": _QUATERNION}))}),
}

# ---------------------------------------------------------------------------------------------
# Messages: pure functions from arrays to JSON-ready dicts.

MAP_FRAME, WORLD_FRAME = "map", "world"
#: world (+Y up) in map (+Z up): +90 deg about X sends world +Y to map +Z.
MAP_TO_WORLD = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])
#: RGBA in [0, 1]: estimated performer, ground truth, avatar.
COLORS = {"skeleton": (1.0, 0.55, 0.1, 1.0), "ground_truth": (0.2, 0.8, 0.3, 1.0), "avatar": (0.25, 0.55, 1.0, 1.0)}
JOINT_DIAMETER_M = 0.05
BONE_THICKNESS_M = 0.02
_IDENTITY_POSE = {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}
_XYZ_FIELDS = [{"name": n, "offset": 4 * i, "type": NUMERIC_TYPES["FLOAT32"]} for i, n in enumerate("xyz")]


def camera_frame(sensor: str) -> str:
    return f"camera_{sensor}"


def foxglove_time(t_ns: int) -> dict:
    """int64 nanoseconds -> Foxglove Time {sec, nsec}."""
    t_ns = int(t_ns)
    if t_ns < 0:
        raise FormatError(f"negative timestamp {t_ns} ns cannot be a Foxglove time")
    return {"sec": t_ns // 1_000_000_000, "nsec": t_ns % 1_000_000_000}


def _color(rgba) -> dict:
    return {"r": float(rgba[0]), "g": float(rgba[1]), "b": float(rgba[2]), "a": float(rgba[3])}


def _xyz(p) -> dict:
    # Rounded to 1 micrometre: float32 noise only makes the JSON longer.
    return {"x": round(float(p[0]), 6), "y": round(float(p[1]), 6), "z": round(float(p[2]), 6)}


def point_cloud_message(points: np.ndarray, t_ns: int, frame_id: str) -> dict:
    """(N, 3) points in frame_id -> foxglove.PointCloud: packed little-endian float32 x,y,z, stride 12."""
    data = np.ascontiguousarray(np.asarray(points).reshape(-1, 3), dtype="<f4").tobytes()
    return {"timestamp": foxglove_time(t_ns), "frame_id": frame_id, "pose": _IDENTITY_POSE, "point_stride": 12,
            "fields": _XYZ_FIELDS, "data": base64.b64encode(data).decode("ascii")}


def decode_point_cloud(message: dict) -> np.ndarray:
    """foxglove.PointCloud with float32 x, y, z fields -> (N, 3) float32 (any stride, any order)."""
    raw = base64.b64decode(message["data"])
    stride = int(message["point_stride"])
    offsets = {f["name"]: int(f["offset"]) for f in message["fields"] if f["type"] == NUMERIC_TYPES["FLOAT32"]}
    if not {"x", "y", "z"} <= offsets.keys() or stride <= 0 or len(raw) % stride:
        raise FormatError("point cloud lacks float32 x, y, z fields or its data is not whole points")
    rows = np.frombuffer(raw, np.uint8).reshape(-1, stride)
    return np.stack([rows[:, offsets[a]:offsets[a] + 4].copy().view("<f4")[:, 0] for a in "xyz"], axis=-1)


def frame_transform(t_ns: int, parent: str, child: str, child_to_parent: np.ndarray) -> dict:
    """A 4x4 rigid child->parent matrix -> foxglove.FrameTransform (child's pose in the parent)."""
    m = np.asarray(child_to_parent, np.float64)
    w, x, y, z = matrix_to_quat(m[:3, :3])
    return {"timestamp": foxglove_time(t_ns), "parent_frame_id": parent, "child_frame_id": child,
            "translation": {"x": float(m[0, 3]), "y": float(m[1, 3]), "z": float(m[2, 3])},
            "rotation": {"x": float(x), "y": float(y), "z": float(z), "w": float(w)}}


def frame_transforms(t_ns: int, camera_poses: dict[str, np.ndarray]) -> dict:
    """foxglove.FrameTransforms of the whole tree: map -> world, world -> camera_<sensor> (4x4 each)."""
    return {"transforms": [frame_transform(t_ns, MAP_FRAME, WORLD_FRAME, MAP_TO_WORLD)]
            + [frame_transform(t_ns, WORLD_FRAME, camera_frame(s), m) for s, m in camera_poses.items()]}


def skeleton_entity(joints: np.ndarray, t_ns: int, entity_id: str, rgba, *, confidence: np.ndarray | None = None,
                    label: str | None = None, frame_id: str = WORLD_FRAME) -> dict:
    """(22, 3) joints -> foxglove.SceneEntity: a sphere per joint, one LINE_LIST of the bones.

    Joints that are not finite are left out, with their bones. With a (22,) confidence in [0, 1],
    a joint's alpha is 0.3 + 0.7 * confidence, so doubtful joints look faint.
    """
    joints = np.asarray(joints, np.float64).reshape(NUM_JOINTS, 3)
    ok = np.all(np.isfinite(joints), axis=1)
    spheres = []
    for j in np.flatnonzero(ok):
        alpha = rgba[3] if confidence is None else rgba[3] * (0.3 + 0.7 * float(np.clip(confidence[j], 0.0, 1.0)))
        spheres.append({"pose": {"position": _xyz(joints[j]), "orientation": _IDENTITY_POSE["orientation"]},
                        "size": {"x": JOINT_DIAMETER_M, "y": JOINT_DIAMETER_M, "z": JOINT_DIAMETER_M},
                        "color": _color((rgba[0], rgba[1], rgba[2], alpha))})
    points = [_xyz(joints[j]) for p, c in BONES if ok[p] and ok[c] for j in (p, c)]
    lines = [{"type": LINE_TYPES["LINE_LIST"], "pose": _IDENTITY_POSE, "thickness": BONE_THICKNESS_M,
              "scale_invariant": False, "points": points, "color": _color(rgba), "colors": [], "indices": []}]
    texts = []
    head = joints[JOINT_INDEX["head"]]
    if label and ok[JOINT_INDEX["head"]]:
        texts.append({"pose": {"position": _xyz(head + (0.0, 0.25, 0.0)), "orientation": _IDENTITY_POSE["orientation"]},
                      "billboard": True, "font_size": 14.0, "scale_invariant": True, "color": _color(rgba),
                      "text": label})
    return {"timestamp": foxglove_time(t_ns), "frame_id": frame_id, "id": entity_id,
            "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": False, "metadata": [],
            "arrows": [], "cubes": [], "spheres": spheres, "cylinders": [], "lines": lines if points else [],
            "triangles": [], "texts": texts, "models": []}


def scene_update(*entities: dict) -> dict:
    return {"deletions": [], "entities": list(entities)}


# ---------------------------------------------------------------------------------------------
# Replay results (skeleton.npz, avatar.npz; contracts in ../shared/CONVENTIONS.md).


@dataclass
class Track:
    """A skeleton over time: t_ns (T,) int64, joints (T, 22, 3) world, confidence (T, 22) or None."""

    t_ns: np.ndarray
    joints: np.ndarray
    confidence: np.ndarray | None = None


def load_skeleton_track(path: str | Path) -> Track:
    """DIR/skeleton.npz (checked by live.io.results.read_skeleton) -> Track with confidence, in
    time order (merging with the session needs it)."""
    skel = read_skeleton(path)
    order = np.argsort(skel.t_ns, kind="stable")
    return Track(skel.t_ns[order], skel.joints.astype(np.float64)[order], skel.confidence.astype(np.float64)[order])


def load_avatar_track(path: str | Path) -> Track:
    """DIR/avatar.npz (checked by live.io.results.read_avatar) -> Track in time order; frames whose
    stored joints are missing (NaN) are rebuilt by forward kinematics from their rotations, root
    and the avatar's rest joints."""
    avatar = read_avatar(path)
    order = np.argsort(avatar.t_ns, kind="stable")
    joints = avatar.joints.astype(np.float64)[order]
    missing = ~np.isfinite(joints).all(axis=(1, 2))
    if missing.any():
        rotations = avatar.rotations.astype(np.float64)[order]
        root = avatar.root.astype(np.float64)[order]
        joints[missing], _ = forward_kinematics(rotations[missing], root[missing],
                                                avatar.rest_joints.astype(np.float64))
    return Track(avatar.t_ns[order], joints)


def avatar_offset_for(avatar: Track, performer: Track | None, camera_to_world: np.ndarray | None,
                      *, distance_m: float = 1.5, overlap_m: float = 1.0) -> np.ndarray:
    """Where to draw the avatar so it does not overlap the performer: (3,) world offset.

    The avatar follows the performer's root (scaled by leg length), so it is drawn ``distance_m``
    to the side (the camera's right, flattened onto the floor; world +x without a camera) unless
    its pelvis is at a median horizontal distance >= ``overlap_m`` from the performer's already.
    """
    if performer is not None and len(performer.t_ns) and len(avatar.t_ns):
        idx = np.clip(np.searchsorted(performer.t_ns, avatar.t_ns), 0, len(performer.t_ns) - 1)
        gap = (avatar.joints[:, 0] - performer.joints[idx, 0])[:, [0, 2]]
        gap = gap[np.isfinite(gap).all(axis=1)]
        if len(gap) and float(np.median(np.linalg.norm(gap, axis=1))) >= overlap_m:
            return np.zeros(3)
    side = np.array([1.0, 0.0, 0.0])
    if camera_to_world is not None:
        right = np.asarray(camera_to_world, np.float64)[:3, 0] * (1.0, 0.0, 1.0)
        if np.linalg.norm(right) > 1e-6:
            side = right / np.linalg.norm(right)
    return side * distance_m


# ---------------------------------------------------------------------------------------------
# The converter.


@dataclass
class FoxgloveExport:
    """What export_foxglove wrote: messages per topic, frames with no Foxglove schema per stream
    (serial bytes, IMU samples), the avatar's drawing offset, and the reader's damage message."""

    path: Path
    messages: dict[str, int] = field(default_factory=dict)
    skipped: dict[str, int] = field(default_factory=dict)
    avatar_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    error: str | None = None


class _Out:
    """The output MCAP: one schema per well-known name, one channel per topic, JSON messages."""

    def __init__(self, path: Path, chunk_size: int):
        path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(path, "wb")
        self._writer = Writer(self._file, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._writer.start(profile="", library=f"livecap {__version__}")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self.counts: dict[str, int] = {}
        self._sequence = 0

    def metadata(self, name: str, data: dict[str, str]) -> None:
        self._writer.add_metadata(name, data)

    def write(self, topic: str, schema: str, t_ns: int, message: dict) -> None:
        if schema not in self._schemas:
            self._schemas[schema] = self._writer.register_schema(
                schema, SchemaEncoding.JSONSchema, json.dumps(SCHEMAS[schema]).encode())
        if topic not in self._channels:
            self._channels[topic] = self._writer.register_channel(topic, MessageEncoding.JSON, self._schemas[schema])
        data = json.dumps(message, separators=(",", ":"), allow_nan=False).encode()
        self._writer.add_message(self._channels[topic], log_time=int(t_ns), data=data, publish_time=int(t_ns),
                                 sequence=self._sequence)
        self._sequence += 1
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def close(self) -> None:
        try:
            self._writer.finish()
        finally:
            self._file.close()


def _track_events(track: Track, topic: str, offset: np.ndarray | None = None) -> Iterator[tuple]:
    shift = np.zeros(3) if offset is None else offset
    for i in range(len(track.t_ns)):
        conf = None if track.confidence is None else track.confidence[i]
        yield int(track.t_ns[i]), topic, track.joints[i] + shift, conf


def _session_events(reader: SessionReader, export: FoxgloveExport) -> Iterator[tuple]:
    for stream, frame in reader.frames():
        if stream.kind in ("depth", "gt"):
            yield int(frame.t_ns), stream.kind, stream, frame
        else:
            export.skipped[stream.name] = export.skipped.get(stream.name, 0) + 1


def export_foxglove(session_path: str | Path, out_path: str | Path, results_dir: str | Path | None = None, *,
                    avatar_offset: tuple[float, float, float] | None = None, max_points: int | None = None,
                    chunk_size: int = 1 << 20) -> FoxgloveExport:
    """Convert a session (and a replay's ``skeleton.npz`` / ``avatar.npz``) into a Foxglove MCAP.

    avatar_offset: world offset (metres) added to the avatar's joints; None picks one with
    ``avatar_offset_for`` (to the side when it would overlap the performer); (0, 0, 0) keeps it
    in place. max_points: keep at most this many points per cloud (uniform stride); None keeps all.
    A damaged session is converted up to the damage; the reason is in the result's ``error``.
    """
    reader = SessionReader(session_path)
    out_path = Path(out_path)
    if out_path.resolve() == reader.path.resolve():
        raise UserInputError(f"the Foxglove export would overwrite its own session: {out_path}")
    if max_points is not None and max_points < 1:
        raise UserInputError(f"max_points must be at least 1, not {max_points}")
    skeleton = avatar = None
    if results_dir is not None:
        results = Path(results_dir)
        if (results / "skeleton.npz").is_file():
            skeleton = load_skeleton_track(results / "skeleton.npz")
        if (results / "avatar.npz").is_file():
            avatar = load_avatar_track(results / "avatar.npz")
        if skeleton is None and avatar is None:
            raise UserInputError(f"no skeleton.npz or avatar.npz in {results} (write them with livecap replay --out)")
    # Camera poses the session declares up front; frames update them as they come.
    poses = {s.name: np.asarray(s.meta["camera_to_world"], np.float64) for s in reader.info.streams
             if s.kind == "depth" and "camera_to_world" in s.meta}
    export = FoxgloveExport(path=out_path)
    offset = np.zeros(3)
    if avatar is not None:
        if avatar_offset is not None:
            offset = np.asarray(avatar_offset, np.float64)
            if offset.shape != (3,) or not np.isfinite(offset).all():
                raise UserInputError(f"avatar_offset must be 3 finite numbers (metres), not {avatar_offset!r}")
        else:
            offset = avatar_offset_for(avatar, skeleton, next(iter(poses.values()), None))
        export.avatar_offset = (float(offset[0]), float(offset[1]), float(offset[2]))
    sources = [_session_events(reader, export)]
    if skeleton is not None:
        sources.append(_track_events(skeleton, "/skeleton"))
    if avatar is not None:
        sources.append(_track_events(avatar, "/avatar", offset))
    out = _Out(out_path, chunk_size)
    try:
        out.metadata("livecap.foxglove", {
            "source": reader.path.name, "livecap_version": __version__,
            "start_wall_time_ns": str(reader.info.start_wall_time_ns),
            "avatar_offset_m": json.dumps(list(export.avatar_offset))})
        tf_time = None
        for t_ns, kind, a, b in heapq.merge(*sources, key=lambda e: e[0]):
            moved = False
            if kind == "depth":
                pose = np.asarray(b.camera_to_world, np.float64)
                moved = b.sensor not in poses or not np.array_equal(poses[b.sensor], pose)
                poses[b.sensor] = pose
            if moved or t_ns != tf_time:
                # The whole tree at every instant: Foxglove's seek back-fills only the latest
                # message of a topic, so each /tf message must be complete on its own.
                out.write("/tf", "foxglove.FrameTransforms", t_ns, frame_transforms(t_ns, poses))
                tf_time = t_ns
            if kind == "depth":
                points = b.cloud()
                if max_points is not None and len(points) > max_points:
                    points = points[:: -(-len(points) // max_points)]
                out.write(f"/depth/{b.sensor}", "foxglove.PointCloud", t_ns,
                          point_cloud_message(points, t_ns, camera_frame(b.sensor)))
            elif kind == "gt":
                out.write("/ground_truth", "foxglove.SceneUpdate", t_ns, scene_update(
                    skeleton_entity(b.joints, t_ns, "ground_truth", COLORS["ground_truth"], label="ground truth")))
            else:
                name = kind.strip("/")
                out.write(kind, "foxglove.SceneUpdate", t_ns, scene_update(
                    skeleton_entity(a, t_ns, name, COLORS[name], confidence=b,
                                    label="performer" if name == "skeleton" else name)))
    finally:
        out.close()
    export.messages = dict(out.counts)
    export.error = reader.error
    return export

