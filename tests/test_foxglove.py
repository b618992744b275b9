"""Foxglove export: the file opens with CRC checks, uses the well-known schemas with JSON, every
message validates against its stored schema, clouds round-trip, counts and geometry match."""

import base64
import binascii
import json

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader

from live.core.depth import points_to_world
from live.core.errors import FormatError, UserInputError
from live.core.frames import AvatarPose, DepthFrame, FrameResult, GroundTruth, MocapPacket, SkeletonFrame
from live.core.kinematics import forward_kinematics
from live.core.protocols import StreamInfo
from live.core.rotations import quat_from_axis_angle, quat_to_matrix
from live.core.skeleton import BONES, NUM_JOINTS, default_rest_joints
from live.io.foxglove import (
    MAP_TO_WORLD,
    SCHEMAS,
    Track,
    avatar_offset_for,
    decode_point_cloud,
    export_foxglove,
    load_avatar_track,
    point_cloud_message,
)
from live.io.results import ResultsWriter, read_skeleton
from live.io.session import SessionReader, SessionWriter

T = 12
T0 = 5_000_000_000
DT = 33_333_333
K = np.array([[60.0, 0, 32], [0, 60.0, 20], [0, 0, 1]])
WELL_KNOWN = {"foxglove.PointCloud", "foxglove.SceneUpdate", "foxglove.FrameTransforms"}


def _pose(yaw, t):
    m = np.eye(4)
    m[:3, :3] = quat_to_matrix(quat_from_axis_angle(np.array([0.0, yaw, 0.0])))
    m[:3, 3] = t
    return m


CAM = _pose(np.pi + 0.3, (0.5, 1.2, 3.0))
CLOUD_A, CLOUD_B = _pose(0.5, (-2.0, 1.0, 2.0)), _pose(0.7, (-2.2, 1.1, 2.0))


def _motion(rng, n=T):
    rest = default_rest_joints()
    rot = quat_from_axis_angle(rng.normal(scale=0.3, size=(n, NUM_JOINTS, 3)))
    root = np.stack([np.linspace(0, 0.5, n), np.full(n, 0.95), np.zeros(n)], axis=-1)
    joints, _ = forward_kinematics(rot, root, rest)
    return rest, rot.astype(np.float32), root.astype(np.float32), joints.astype(np.float32)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A session (depth image camera, moving point-cloud camera, serial suit, ground truth) and a
    replay's results written by the real ResultsWriter."""
    rng = np.random.default_rng(7)
    root_dir = tmp_path_factory.mktemp("fox")
    rest, rot, root, joints = _motion(rng)
    session = root_dir / "s.mcap"
    streams = [StreamInfo("cam", "depth", {"camera_to_world": CAM.tolist(), "intrinsics": K.tolist()}),
               StreamInfo("cloud", "depth", {}), StreamInfo("suit", "serial", {}), StreamInfo("gt", "gt", {})]
    with SessionWriter(session, streams, chunk_size=8 * 1024) as w:
        for i in range(T):
            t = T0 + i * DT
            w.write(MocapPacket(t - 1000, "suit", raw=bytes(rng.integers(0, 256, 20).astype(np.uint8))))
            w.write(GroundTruth(t, joints[i], rot[i], root[i]))
            img = rng.integers(500, 4000, size=(40, 64)).astype(np.uint16)
            img[rng.random(img.shape) < 0.3] = 0
            w.write(DepthFrame(t, "cam", camera_to_world=CAM, depth_mm=img, intrinsics=K))
            w.write(DepthFrame(t + 2000, "cloud", camera_to_world=CLOUD_A if i < T // 2 else CLOUD_B,
                               points=rng.uniform(-2, 2, size=(50 + i, 3)).astype(np.float32)))
    results = root_dir / "results"
    rw = ResultsWriter(results, avatar_rest_joints=rest)
    for i in range(T):
        t = T0 + i * DT
        est = joints[i] + rng.normal(scale=0.01, size=(NUM_JOINTS, 3)).astype(np.float32)
        est[3] = np.nan if i == 2 else est[3]  # a lost joint must not reach the JSON
        conf = rng.uniform(0, 1, NUM_JOINTS).astype(np.float32)
        # Frame 4's avatar joints were not computed: the exporter rebuilds them by FK.
        av_joints = None if i == 4 else joints[i]
        rw.send(FrameResult(t, skeleton=SkeletonFrame(t, est, conf),
                            avatar=AvatarPose(t, root[i], rot[i], joints=av_joints)))
    rw.close()
    out = root_dir / "fox.mcap"
    export = export_foxglove(session, out, results)
    return {"session": session, "results": results, "out": out, "export": export, "joints": joints}


def _read(path):
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        msgs = [(schema, channel, message, json.loads(message.data))
                for schema, channel, message in reader.iter_messages(log_time_order=False)]
    return summary, msgs


def _of(msgs, topic):
    return [(m, d) for _, c, m, d in msgs if c.topic == topic]


# A JSON Schema check of what the schemas use (types, required, enums, bounds, base64), strict
# about unknown fields so a typo in a field name cannot pass.
_TYPES = {"object": dict, "array": list, "string": str, "boolean": bool}


def _check(value, schema, where="$"):
    if "oneOf" in schema:
        hits = [s for s in schema["oneOf"] if "const" in s and value == s["const"] and type(value) is int]
        assert len(hits) == 1, f"{where}: {value!r} is not one of {schema['title']}"
        return
    kind = schema["type"]
    if kind == "number":
        assert isinstance(value, (int, float)) and not isinstance(value, bool), f"{where}: not a number"
    elif kind == "integer":
        assert isinstance(value, int) and not isinstance(value, bool), f"{where}: not an integer"
    else:
        assert isinstance(value, _TYPES[kind]), f"{where}: not a {kind}"
    if "minimum" in schema:
        assert value >= schema["minimum"], f"{where}: below minimum"
    if "maximum" in schema:
        assert value <= schema["maximum"], f"{where}: above maximum"
    if schema.get("contentEncoding") == "base64":
        base64.b64decode(value, validate=True)
    if kind == "object":
        missing = set(schema.get("required", [])) - value.keys()
        assert not missing, f"{where}: missing {sorted(missing)}"
        unknown = value.keys() - schema["properties"].keys()
        assert not unknown, f"{where}: unknown fields {sorted(unknown)}"
        for key, sub in value.items():
            _check(sub, schema["properties"][key], f"{where}.{key}")
    if kind == "array":
        for i, item in enumerate(value):
            _check(item, schema["items"], f"{where}[{i}]")


def test_file_opens_with_crc_checks_and_uses_well_known_schemas(recorded):
    with open(recorded["out"], "rb") as f:  # every record, chunk CRCs included
        records = list(StreamReader(f, validate_crcs=True).records)
    assert records
    summary, msgs = _read(recorded["out"])
    names = {s.name: s for s in summary.schemas.values()}
    assert set(names) == WELL_KNOWN
    assert all(s.encoding == "jsonschema" for s in names.values())
    assert all(json.loads(s.data)["title"] == s.name for s in names.values())
    topics = {c.topic: (c.message_encoding, summary.schemas[c.schema_id].name) for c in summary.channels.values()}
    assert topics == {"/tf": ("json", "foxglove.FrameTransforms"),
                      "/depth/cam": ("json", "foxglove.PointCloud"), "/depth/cloud": ("json", "foxglove.PointCloud"),
                      "/ground_truth": ("json", "foxglove.SceneUpdate"), "/skeleton": ("json", "foxglove.SceneUpdate"),
                      "/avatar": ("json", "foxglove.SceneUpdate")}
    # Written in time order, so Foxglove never has to sort.
    times = [m.log_time for _, _, m, _ in msgs]
    assert times == sorted(times)


def test_every_message_validates_against_its_stored_schema(recorded):
    summary, msgs = _read(recorded["out"])
    try:
        import jsonschema
    except ImportError:  # the hand-written check below still runs
        jsonschema = None
    for schema, channel, message, data in msgs:
        stored = json.loads(schema.data)
        assert stored == SCHEMAS[schema.name]
        _check(data, stored, channel.topic)
        if jsonschema is not None:
            jsonschema.Draft202012Validator(stored).validate(data)
        ts = data.get("timestamp") or (data.get("entities") or data.get("transforms"))[0]["timestamp"]
        assert ts["sec"] * 1_000_000_000 + ts["nsec"] == message.log_time == message.publish_time


def test_validator_catches_broken_messages():
    msg = point_cloud_message(np.zeros((2, 3), np.float32), 1, "f")
    _check(msg, SCHEMAS["foxglove.PointCloud"])
    for broken in ({**msg, "point_stride": -1}, {k: v for k, v in msg.items() if k != "pose"},
                   {**msg, "fields": [{"name": "x", "offset": 0, "type": 9}]}, {**msg, "extra": 1},
                   {**msg, "data": "not base64!"}):
        with pytest.raises((AssertionError, binascii.Error)):
            _check(broken, SCHEMAS["foxglove.PointCloud"])


def test_counts_match_the_session(recorded):
    export = recorded["export"]
    assert export.error is None
    assert export.skipped == {"suit": T}  # raw serial bytes have no Foxglove schema
    _, msgs = _read(recorded["out"])
    counts = {}
    for _, c, _, _ in msgs:
        counts[c.topic] = counts.get(c.topic, 0) + 1
    assert counts == export.messages
    for topic in ("/depth/cam", "/depth/cloud", "/ground_truth", "/skeleton", "/avatar"):
        assert counts[topic] == T, topic
    # One complete tree per distinct instant: the camera and the cloud sensor log at different ns.
    assert counts["/tf"] == 2 * T


def test_point_clouds_round_trip_in_their_camera_frame(recorded):
    _, msgs = _read(recorded["out"])
    originals = {"cam": [], "cloud": []}
    for stream, frame in SessionReader(recorded["session"]).frames():
        if stream.kind == "depth":
            originals[stream.name].append((frame.t_ns, frame.cloud()))
    for sensor, frames in originals.items():
        got = _of(msgs, f"/depth/{sensor}")
        assert len(got) == len(frames)
        for (m, d), (t, pts) in zip(got, frames):
            assert m.log_time == t and d["frame_id"] == f"camera_{sensor}"
            back = decode_point_cloud(d)
            assert back.dtype == np.float32
            np.testing.assert_array_equal(back, pts.astype(np.float32))


def _matrix(tf):
    m = np.eye(4)
    r, t = tf["rotation"], tf["translation"]
    m[:3, :3] = quat_to_matrix(np.array([r["w"], r["x"], r["y"], r["z"]]))
    m[:3, 3] = (t["x"], t["y"], t["z"])
    return m


def test_transforms_place_clouds_in_the_world_and_world_upright_in_map(recorded):
    _, msgs = _read(recorded["out"])
    tfs = _of(msgs, "/tf")
    # Every /tf message holds the whole tree (Foxglove's seek keeps only a topic's latest message).
    for _m, d in tfs[1:]:
        assert {(t["parent_frame_id"], t["child_frame_id"]) for t in d["transforms"]} == {
            ("map", "world"), ("world", "camera_cam"), ("world", "camera_cloud")}
    map_world = _matrix(tfs[0][1]["transforms"][0])
    np.testing.assert_allclose(map_world, MAP_TO_WORLD, atol=1e-12)
    np.testing.assert_allclose(map_world[:3, :3] @ [0, 1, 0], [0, 0, 1], atol=1e-12)  # world up -> map up
    # The cloud camera moved half-way: the transform valid at each cloud puts its points where
    # points_to_world does with the session's camera_to_world.
    frames = [f for s, f in SessionReader(recorded["session"]).frames() if s.name == "cloud"]
    for frame, (m, d) in zip(frames, _of(msgs, "/depth/cloud")):
        latest = [td for tm, td in tfs if tm.log_time <= m.log_time][-1]
        tf = next(t for t in latest["transforms"] if t["child_frame_id"] == "camera_cloud")
        pts = decode_point_cloud(d).astype(np.float64)
        world = pts @ _matrix(tf)[:3, :3].T + _matrix(tf)[:3, 3]
        np.testing.assert_allclose(world, points_to_world(frame.points, frame.camera_to_world), atol=1e-5)


def _spheres(d):
    return np.array([[s["pose"]["position"][a] for a in "xyz"] for s in d["entities"][0]["spheres"]])


def test_skeletons_are_spheres_and_bone_line_lists(recorded):
    _, msgs = _read(recorded["out"])
    joints = recorded["joints"]
    skel = read_skeleton(recorded["results"] / "skeleton.npz")
    for i, (_m, d) in enumerate(_of(msgs, "/ground_truth")):
        e = d["entities"][0]
        assert e["frame_id"] == "world" and e["id"] == "ground_truth"
        np.testing.assert_allclose(_spheres(d), joints[i], atol=1e-6)
        (line,) = e["lines"]
        assert line["type"] == 2  # LINE_LIST
        pts = np.array([[p[a] for a in "xyz"] for p in line["points"]])
        np.testing.assert_allclose(pts, joints[i][np.array(BONES).ravel()], atol=1e-6)
    for i, (_m, d) in enumerate(_of(msgs, "/skeleton")):
        ok = np.isfinite(skel.joints[i]).all(axis=1)
        np.testing.assert_allclose(_spheres(d), skel.joints[i][ok], atol=1e-6)
        alphas = [s["color"]["a"] for s in d["entities"][0]["spheres"]]
        np.testing.assert_allclose(alphas, 0.3 + 0.7 * skel.confidence[i][ok], atol=1e-6)
        n_bones = sum(ok[p] and ok[c] for p, c in BONES)
        assert len(d["entities"][0]["lines"][0]["points"]) == 2 * n_bones
    assert len(_spheres(_of(msgs, "/skeleton")[2][1])) == NUM_JOINTS - 1  # the lost joint is left out
    colors = {t: _of(msgs, t)[0][1]["entities"][0]["lines"][0]["color"]["r"]
              for t in ("/skeleton", "/ground_truth", "/avatar")}
    assert len(set(colors.values())) == 3


def test_avatar_is_drawn_beside_the_performer(recorded):
    _, msgs = _read(recorded["out"])
    offset = np.array(recorded["export"].avatar_offset)
    assert np.linalg.norm(offset) == pytest.approx(1.5) and offset[1] == 0.0
    # To the camera's right (flattened), so both stand side by side in the camera's view.
    right = CAM[:3, 0] * (1, 0, 1)
    assert offset @ right / np.linalg.norm(right) == pytest.approx(1.5)
    avatar = load_avatar_track(recorded["results"] / "avatar.npz")
    assert np.isfinite(avatar.joints).all()  # frame 4 rebuilt by FK
    np.testing.assert_allclose(avatar.joints, recorded["joints"], atol=1e-5)
    for i, (_m, d) in enumerate(_of(msgs, "/avatar")):
        np.testing.assert_allclose(_spheres(d) - offset, recorded["joints"][i], atol=1e-5)


def test_avatar_offset_rules():
    rng = np.random.default_rng(1)
    _, _, _, joints = _motion(rng, 5)
    t = np.arange(5, dtype=np.int64)
    performer = Track(t, joints.astype(np.float64))
    near = Track(t, joints + 0.05)
    far = Track(t, joints + np.array([2.0, 0, 0]))
    np.testing.assert_allclose(avatar_offset_for(near, performer, None), [1.5, 0, 0])
    np.testing.assert_allclose(avatar_offset_for(far, performer, None), [0, 0, 0])
    np.testing.assert_allclose(avatar_offset_for(near, None, np.eye(4)), [1.5, 0, 0])


def test_options_offset_and_decimation(recorded, tmp_path):
    out = tmp_path / "o.mcap"
    export = export_foxglove(recorded["session"], out, recorded["results"], avatar_offset=(0, 0, 0), max_points=40)
    assert export.avatar_offset == (0.0, 0.0, 0.0)
    _, msgs = _read(out)
    for i, (_m, d) in enumerate(_of(msgs, "/avatar")):
        np.testing.assert_allclose(_spheres(d), recorded["joints"][i], atol=1e-5)
    for _, d in _of(msgs, "/depth/cam") + _of(msgs, "/depth/cloud"):
        assert 0 < len(decode_point_cloud(d)) <= 40


def test_session_only_export(recorded, tmp_path):
    export = export_foxglove(recorded["session"], tmp_path / "o.mcap")
    assert set(export.messages) == {"/tf", "/depth/cam", "/depth/cloud", "/ground_truth"}


def test_damaged_session_converts_up_to_the_damage(recorded, tmp_path):
    data = recorded["session"].read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    export = export_foxglove(cut, tmp_path / "o.mcap")
    assert export.error and "truncated" in export.error
    summary, msgs = _read(tmp_path / "o.mcap")
    assert 0 < export.messages["/depth/cam"] < T and len(msgs) == sum(export.messages.values())


def test_bad_inputs(recorded, tmp_path):
    with pytest.raises(UserInputError, match="no skeleton.npz"):
        export_foxglove(recorded["session"], tmp_path / "o.mcap", tmp_path)
    with pytest.raises(UserInputError, match="overwrite"):
        export_foxglove(recorded["session"], recorded["session"])
    with pytest.raises(UserInputError, match="no such session"):
        export_foxglove(tmp_path / "missing.mcap", tmp_path / "o.mcap")
    bad = tmp_path / "bad"
    bad.mkdir()
    np.savez(bad / "skeleton.npz", t_ns=np.arange(3), joints=np.zeros((3, 21, 3)), confidence=np.zeros((3, 21)))
    with pytest.raises(FormatError, match=r"joints is \(3, 21, 3\), expected \(3, 22, 3\)"):
        export_foxglove(recorded["session"], tmp_path / "o.mcap", bad)
    (bad / "skeleton.npz").write_bytes(b"garbage")
    with pytest.raises(FormatError, match="not a readable"):
        export_foxglove(recorded["session"], tmp_path / "o.mcap", bad)
    (bad / "skeleton.npz").write_bytes(b"PK\x03\x04" + b"\x00" * 40)  # a broken zip
    with pytest.raises(FormatError, match="not a readable"):
        export_foxglove(recorded["session"], tmp_path / "o.mcap", bad)
    np.savez(bad / "skeleton.npz", t_ns=np.arange(3), joints=np.zeros((3, 22, 3)))
    with pytest.raises(FormatError, match="missing arrays confidence"):
        export_foxglove(recorded["session"], tmp_path / "o.mcap", bad)


def test_results_out_of_order_are_sorted(recorded, tmp_path):
    skel = dict(np.load(recorded["results"] / "skeleton.npz"))
    flipped = tmp_path / "flipped"
    flipped.mkdir()
    np.savez(flipped / "skeleton.npz", **{k: v[::-1] for k, v in skel.items()})
    export = export_foxglove(recorded["session"], tmp_path / "o.mcap", flipped)
    _, msgs = _read(tmp_path / "o.mcap")
    got = _of(msgs, "/skeleton")
    assert export.messages["/skeleton"] == T and [m.log_time for m, _ in got] == sorted(skel["t_ns"].tolist())
    for i, (_, d) in enumerate(got):
        ok = np.isfinite(skel["joints"][i]).all(axis=1)
        np.testing.assert_allclose(_spheres(d), skel["joints"][i][ok], atol=1e-6)


def test_bad_avatar_offset(recorded, tmp_path):
    with pytest.raises(UserInputError, match="avatar_offset"):
        export_foxglove(recorded["session"], tmp_path / "o.mcap", recorded["results"], avatar_offset=(1, 2))
