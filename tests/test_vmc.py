"""VMC output: Unity frame conversion, bone mapping, and a real OSC server on loopback that
decodes every bundle and rebuilds the pose."""

from __future__ import annotations

import socket
import threading

import numpy as np
import pytest
from pythonosc.dispatcher import Dispatcher
from pythonosc.osc_server import BlockingOSCUDPServer

from live.core.errors import UserInputError
from live.core.frames import AvatarPose, FrameResult, SkeletonFrame
from live.core.kinematics import forward_kinematics
from live.core.rotations import quat_from_axis_angle, quat_normalize, quat_to_matrix
from live.core.skeleton import JOINT_INDEX, PARENTS, default_rest_joints
from live.outputs.unity import (
    JOINT_TO_UNITY_BONE,
    UNITY_BONES,
    position_from_unity,
    position_to_unity,
    quat_from_unity,
    quat_to_unity,
)
from live.outputs.vmc import VmcSink, encode_bundle, encode_bundles, pose_from_vmc, vmc_messages

M = np.diag([-1.0, 1.0, 1.0])

# Unity's HumanBodyBones hierarchy for the bones we drive (child -> parent).
UNITY_PARENT = {
    "Spine": "Hips", "Chest": "Spine", "UpperChest": "Chest", "Neck": "UpperChest", "Head": "Neck",
    "LeftShoulder": "UpperChest", "RightShoulder": "UpperChest",
    "LeftUpperArm": "LeftShoulder", "RightUpperArm": "RightShoulder",
    "LeftLowerArm": "LeftUpperArm", "RightLowerArm": "RightUpperArm",
    "LeftHand": "LeftLowerArm", "RightHand": "RightLowerArm",
    "LeftUpperLeg": "Hips", "RightUpperLeg": "Hips", "LeftLowerLeg": "LeftUpperLeg",
    "RightLowerLeg": "RightUpperLeg", "LeftFoot": "LeftLowerLeg", "RightFoot": "RightLowerLeg",
    "LeftToes": "LeftFoot", "RightToes": "RightFoot",
}


def _random_quats(rng, shape, scale=0.6):
    return quat_from_axis_angle(rng.normal(0.0, scale, shape + (3,)))


def test_quaternion_conversion_is_the_x_mirror_of_the_rotation():
    rng = np.random.default_rng(1)
    q = quat_normalize(rng.normal(size=(64, 4)))
    q_u = quat_to_unity(q)  # (x, y, z, w)
    r_u = quat_to_matrix(np.concatenate([q_u[:, 3:], q_u[:, :3]], axis=1))
    np.testing.assert_allclose(r_u, M @ quat_to_matrix(q) @ M, atol=1e-12)
    np.testing.assert_allclose(quat_from_unity(q_u), q, atol=1e-15)
    p = rng.normal(size=(10, 3))
    np.testing.assert_allclose(position_to_unity(p)[:, 0], -p[:, 0])
    np.testing.assert_allclose(position_from_unity(position_to_unity(p)), p)


def test_bone_map_covers_22_joints_and_matches_unity_hierarchy():
    assert len(set(UNITY_BONES)) == 22
    assert JOINT_TO_UNITY_BONE["pelvis"] == "Hips" and JOINT_TO_UNITY_BONE["left_foot"] == "LeftToes"
    for j, bone in enumerate(UNITY_BONES):
        if PARENTS[j] < 0:
            assert bone == "Hips"
        else:
            assert UNITY_PARENT[bone] == UNITY_BONES[PARENTS[j]], bone
    # A Unity humanoid faces +Z with its left hand at -X.
    rest = default_rest_joints()
    assert position_to_unity(rest[JOINT_INDEX["left_wrist"]])[0] < 0


def test_unity_local_values_reproduce_the_mirrored_pose():
    """FK done entirely in Unity's frame with the sent local values lands on the mirror of ours."""
    rng = np.random.default_rng(2)
    rest = default_rest_joints()
    rot = _random_quats(rng, (22,))
    root = np.array([0.3, 0.9, -0.4])
    ours, _ = forward_kinematics(rot, root, rest)
    msgs = vmc_messages(root, rot, rest, t_s=0.0)
    bones = {args[0]: np.array(args[1:]) for addr, args in msgs if addr == "/VMC/Ext/Bone/Pos"}
    q_u = np.array([bones[b][3:] for b in UNITY_BONES])
    rest_u = position_to_unity(rest)
    unity, _ = forward_kinematics(np.concatenate([q_u[:, 3:], q_u[:, :3]], axis=1), bones["Hips"][:3], rest_u)
    np.testing.assert_allclose(unity, position_to_unity(ours), atol=1e-9)


def test_bundle_layout_follows_the_vmc_spec():
    rest = default_rest_joints()
    msgs = vmc_messages(np.zeros(3), np.tile([1.0, 0, 0, 0], (22, 1)), rest, t_s=1.5, tracking_ok=False)
    assert [a for a, _ in msgs[:3]] == ["/VMC/Ext/OK", "/VMC/Ext/T", "/VMC/Ext/Root/Pos"]
    assert msgs[0][1] == [1, 3, 0, 0]
    assert msgs[1][1] == [1.5]
    assert msgs[2][1][0] == "root" and len(msgs[2][1]) == 8
    assert [args[0] for _, args in msgs[3:]] == list(UNITY_BONES)
    dgram = encode_bundle(msgs)
    assert dgram.startswith(b"#bundle\x00")
    assert b",iiii\x00" in dgram and b",sfffffff\x00" in dgram


def test_receiver_composes_a_rotated_root_with_the_hips():
    """Senders that move the root object (not only the Hips) are rebuilt to the same pose."""
    from live.core.rotations import quat_conjugate, quat_multiply, quat_rotate

    rng = np.random.default_rng(4)
    rot = _random_quats(rng, (22,))
    pelvis = np.array([0.4, 0.92, -1.1])
    root_t = np.array([1.0, 0.0, 2.0])
    root_q = quat_from_axis_angle(np.array([0.0, 0.8, 0.0]))  # yaw, in our frame
    inv = quat_conjugate(root_q)
    hips_pos = quat_rotate(inv, pelvis - root_t)  # Hips local to the rotated root
    hips_rot = quat_multiply(inv, rot[0])
    bones = {b: (0.0, 0.0, 0.0, *quat_to_unity(rot[j])) for j, b in enumerate(UNITY_BONES)}
    bones["Hips"] = (*position_to_unity(hips_pos), *quat_to_unity(hips_rot))
    pose = pose_from_vmc(bones, (*position_to_unity(root_t), *quat_to_unity(root_q)))
    np.testing.assert_allclose(pose.root, pelvis, atol=1e-12)
    np.testing.assert_allclose(pose.rotations, rot, atol=1e-12)


class _Marionette:
    """A VMC receiver: a real OSC server on a free loopback port, rebuilding each bundle's pose."""

    def __init__(self):
        self.poses = []
        self._cond = threading.Condition()
        self._bones, self._root, self._t, self._ok = {}, None, None, None
        d = Dispatcher()
        d.map("/VMC/Ext/OK", self._on_ok)
        d.map("/VMC/Ext/T", self._on_t)
        d.map("/VMC/Ext/Root/Pos", self._on_root)
        d.map("/VMC/Ext/Bone/Pos", self._on_bone)
        self.server = BlockingOSCUDPServer(("127.0.0.1", 0), d)
        # Room for a burst of bundles while this thread catches up.
        self.server.socket.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        self.port = self.server.server_address[1]
        self._thread = threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
        self._thread.start()

    def _on_ok(self, _addr, *args):
        self._ok, self._bones = args, {}  # OK opens each bundle

    def _on_t(self, _addr, t):
        self._t = t

    def _on_root(self, _addr, name, *values):
        assert name == "root"
        self._root = values

    def _on_bone(self, _addr, name, *values):
        self._bones[name] = values
        if len(self._bones) == 22:
            pose = pose_from_vmc(self._bones, self._root, self._t, bool(self._ok[3]))
            with self._cond:
                self.poses.append((pose, self._ok))
                self._cond.notify_all()

    def wait_for(self, n, timeout=10.0):
        with self._cond:
            assert self._cond.wait_for(lambda: len(self.poses) >= n, timeout), f"got {len(self.poses)} of {n}"

    def close(self):
        self.server.shutdown()
        self.server.server_close()
        self._thread.join(timeout=5)


@pytest.fixture
def marionette():
    m = _Marionette()
    yield m
    m.close()


def _motion(n, seed=0):
    """A smooth random motion: (n, 22, 4) rotations and (n, 3) roots."""
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0, 2 * np.pi, (22, 3))
    amp = rng.uniform(0.1, 0.8, (22, 3))
    t = np.arange(n)[:, None, None] / 60.0
    rot = quat_from_axis_angle(amp * np.sin(2 * np.pi * 0.7 * t + phase))
    root = np.stack([np.sin(np.arange(n) / 50.0), 0.9 + 0.05 * np.cos(np.arange(n) / 9.0), np.arange(n) / 300.0], -1)
    return rot, root


def _result(i, rot, root, conf=0.9):
    t_ns = 5_000_000_000 + i * 16_666_667
    skel = SkeletonFrame(t_ns=t_ns, joints=np.zeros((22, 3)), confidence=np.full(22, conf))
    return FrameResult(t_ns=t_ns, skeleton=skel, avatar=AvatarPose(t_ns=t_ns, root=root, rotations=rot))


def test_replay_at_full_speed_delivers_every_frame_exactly(marionette):
    n = 300
    rot, root = _motion(n)
    sink = VmcSink("127.0.0.1", marionette.port, rate_hz=None)
    for start in range(0, n, 50):
        for i in range(start, start + 50):
            sink.send(_result(i, rot[i], root[i], conf=0.1 if i == 7 else 0.9))
        marionette.wait_for(start + 50)  # flow control: a burst never outruns the socket buffer
    sink.close()
    assert sink.stats() == {"sent": n, "bundles": n, "coalesced": 0, "skipped": 0, "refused": 0, "errors": 0}
    assert len(marionette.poses) == n
    for i, (pose, ok) in enumerate(marionette.poses):
        assert ok[:3] == (1, 3, 0)
        assert pose.tracking_ok == (i != 7)
        np.testing.assert_allclose(pose.rotations, quat_normalize(rot[i]), atol=1e-6)
        np.testing.assert_allclose(pose.root, root[i], rtol=1e-6, atol=1e-6)
        assert pose.t_s == pytest.approx(i * 0.016666667, abs=1e-5)


def test_rate_limit_coalesces_to_the_latest_frame(marionette):
    n = 300
    rot, root = _motion(n, seed=3)
    clock_now = [0.0]
    sink = VmcSink("127.0.0.1", marionette.port, rate_hz=60, clock=lambda: clock_now[0])
    for i in range(n):
        clock_now[0] = i * 0.005  # frames at 200 Hz, 1.5 s
        sink.send(_result(i, rot[i], root[i]))
    sink.close()  # delivers the last, held-back frame
    assert 1.5 * 60 <= sink.sent <= 1.5 * 60 + 2
    assert sink.sent + sink.coalesced == n
    marionette.wait_for(sink.sent)
    last, _ = marionette.poses[-1]
    np.testing.assert_allclose(last.rotations, quat_normalize(rot[-1]), atol=1e-6)
    times = [p.t_s for p, _ in marionette.poses]
    assert times == sorted(times)


def test_send_never_raises_and_counts_problems(marionette):
    sink = VmcSink("127.0.0.1", marionette.port, rate_hz=None)
    sink.send(FrameResult(t_ns=1))  # no avatar: skipped
    bad = AvatarPose(t_ns=2, root=np.zeros(3), rotations=np.zeros((21, 4)))
    sink.send(FrameResult(t_ns=2, avatar=bad))
    sink.close()
    sink.send(FrameResult(t_ns=3))  # after close: ignored
    assert sink.skipped == 1 and sink.errors == 1 and sink.sent == 0


def test_socket_is_connected_to_its_target_and_hears_no_one_else(marionette):
    sink = VmcSink("127.0.0.1", marionette.port, rate_hz=None)
    rot, root = _motion(1)
    sink.send(_result(0, rot[0], root[0]))
    local = sink._sock.getsockname()
    assert sink._sock.getpeername() == ("127.0.0.1", marionette.port)
    assert local[0] == "127.0.0.1"  # bound to the interface that routes to the target, not 0.0.0.0
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stranger:
        stranger.sendto(b"/VMC/Ext/hello", local)
        stranger.sendto(b"/VMC/Ext/hello", local)
    with pytest.raises(BlockingIOError):  # the kernel dropped the stranger's datagrams
        sink._sock.recv(100, socket.MSG_DONTWAIT)
    sink.close()
    assert sink.sent == 1 and sink.errors == 0


def test_no_receiver_is_counted_as_refused_not_as_errors():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # a port nobody listens on once this socket is closed
    sink = VmcSink("127.0.0.1", port, rate_hz=None)
    rot, root = _motion(5)
    for i in range(5):
        sink.send(_result(i, rot[i], root[i]))
    sink.close()
    assert sink.errors == 0 and sink.refused >= 1 and sink.sent + sink.refused == 5


@pytest.mark.parametrize("kwargs", [{"port": 0}, {"port": 70000}, {"rate_hz": 0}, {"host": ""},
                                    {"avatar_rest_joints": np.zeros((21, 3))}])
def test_bad_settings_are_user_errors(kwargs):
    with pytest.raises(UserInputError):
        VmcSink(**kwargs)


def test_real_clip_replayed_over_vmc_rebuilds_the_motion(marionette, shared_bvh):
    """A CMU clip sent at full speed: FK of what the marionette rebuilt lands on the clip's joints."""
    from live.motion.rig_mapping import load_motion

    motion = load_motion(shared_bvh / "cc_002_01.bvh")
    n = len(motion.rotations)
    sink = VmcSink("127.0.0.1", marionette.port, rate_hz=None, avatar_rest_joints=motion.rest_joints)
    for start in range(0, n, 50):
        stop = min(start + 50, n)
        for i in range(start, stop):
            sink.send(_result(i, motion.rotations[i], motion.root[i]))
        marionette.wait_for(stop)
    sink.close()
    assert sink.sent == n and sink.errors == 0
    rot = np.stack([p.rotations for p, _ in marionette.poses])
    root = np.stack([p.root for p, _ in marionette.poses])
    joints, _ = forward_kinematics(rot, root, motion.rest_joints)
    np.testing.assert_allclose(joints, motion.joints, atol=2e-5)


def test_replay_vmc_without_avatar_sends_the_default_one_at_the_takes_pace(marionette, tmp_path, capsys):
    """`replay S --vmc` with no --avatar: the default avatar, one line saying so; unset --speed
    means recorded timing with --vmc; stats.json counts the bundles."""
    import json

    from live.app.cli import main
    from live.core.frames import DepthFrame
    from live.core.protocols import StreamInfo
    from live.io.session import SessionWriter

    k = np.array([[200.0, 0, 32], [0, 200.0, 20], [0, 0, 1]])
    rng = np.random.default_rng(3)
    session = tmp_path / "s.mcap"
    with SessionWriter(session, [StreamInfo("cam", "depth", {"fps": 30})]) as w:
        for i in range(12):
            w.write(DepthFrame(i * 33_333_333, "cam", depth_mm=rng.integers(500, 4000, (40, 64)).astype(np.uint16),
                               intrinsics=k))
    out = tmp_path / "out"
    assert main(["replay", str(session), "--out", str(out), "--quiet", "--vmc", f"127.0.0.1:{marionette.port}",
                 "--vmc-rate", "0"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["livecap: --vmc without --avatar: sending the default avatar (choose one with --avatar)"]
    stats = json.loads((out / "stats.json").read_text())
    counters = stats["sinks"]["vmc"]["counters"]
    assert counters["sent"] > 0 and counters["sent"] + counters["skipped"] == 12  # skipped: no pose (noise)
    assert counters["coalesced"] == counters["refused"] == counters["errors"] == 0
    marionette.wait_for(counters["sent"])
    assert stats["wall_s"] >= 11 * 0.0333  # paced: the frames went out over the take's 0.37 s


def test_unset_speed_is_max_except_with_vmc():
    from argparse import Namespace

    from live.app.commands import replay_speed

    assert replay_speed(Namespace(speed=None, vmc=None)) == "max"
    assert replay_speed(Namespace(speed=None, vmc="127.0.0.1:39539")) == "1"
    assert replay_speed(Namespace(speed="max", vmc="127.0.0.1:39539")) == "max"
    assert replay_speed(Namespace(speed="2", vmc=None)) == "2"


def test_bundles_split_to_fit_an_mtu_keep_every_message_in_order():
    from pythonosc.osc_bundle import OscBundle

    from live.outputs.vmc import MIN_BUNDLE_BYTES

    rot, root = _motion(1)
    msgs = vmc_messages(root[0], rot[0], default_rest_joints(), 0.5)
    whole = encode_bundle(msgs)
    assert len(whole) > 1500  # one frame is above an Ethernet MTU
    for limit in (MIN_BUNDLE_BYTES, 600, 1400):
        parts = encode_bundles(msgs, limit)
        assert len(parts) >= -(-len(whole) // limit)  # no fewer than the bytes need
        assert all(len(p) <= limit for p in parts)
        got = [(m.address, list(m.params)) for p in parts for m in OscBundle(p)]
        want = [(m.address, list(m.params)) for m in OscBundle(whole)]
        assert got == want and got[0][0] == "/VMC/Ext/OK"
    assert encode_bundles(msgs) == [whole]
    with pytest.raises(UserInputError):
        encode_bundles(msgs, 100)
    with pytest.raises(UserInputError):
        VmcSink("127.0.0.1", 39539, max_bundle_bytes=70000)


def test_split_frames_rebuild_the_same_poses(marionette):
    rot, root = _motion(20, seed=4)
    with VmcSink("127.0.0.1", marionette.port, rate_hz=None, max_bundle_bytes=1400) as sink:
        for i in range(20):
            sink.send(_result(i, rot[i], root[i]))
    assert sink.sent == 20 and sink.bundles == 40 and sink.errors == 0
    marionette.wait_for(20)
    for i, (pose, _ok) in enumerate(marionette.poses):
        np.testing.assert_allclose(pose.root, root[i], atol=1e-5)
        np.testing.assert_allclose(np.abs(np.sum(pose.rotations * quat_normalize(rot[i]), -1)), 1.0, atol=1e-5)


def _received_bones(extra_bones, rest, frames=1, **kwargs):
    """Send ``frames`` rest-pose frames to a plain loopback UDP socket; per frame, bone -> values."""
    from pythonosc.osc_bundle import OscBundle

    rot, root = np.tile([1.0, 0.0, 0.0, 0.0], (22, 1)), np.asarray(rest[0], np.float64)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx:
        rx.bind(("127.0.0.1", 0))
        rx.settimeout(5.0)
        with VmcSink("127.0.0.1", rx.getsockname()[1], rate_hz=None, avatar_rest_joints=rest,
                     extra_bones=extra_bones, **kwargs) as sink:
            for i in range(frames):
                sink.send(_result(i, rot, root))
        datagrams = [rx.recv(65536) for _ in range(sink.bundles)]
    out, sizes = [], [len(d) for d in datagrams]
    for d in datagrams:
        for msg in OscBundle(d):
            if msg.address == "/VMC/Ext/OK":
                out.append({})
            elif msg.address == "/VMC/Ext/Bone/Pos":
                out[-1][msg.params[0]] = np.asarray(msg.params[1:], np.float64)
    return out, sizes


def test_extra_bones_go_at_rest_after_the_22():
    from live.body.body import ExtraBone

    rest = default_rest_joints()
    extra = (ExtraBone("LeftIndexProximal", "left_wrist", (0.09, -0.003, 0.017)),
             ExtraBone("LeftIndexIntermediate", "LeftIndexProximal", (0.025, 0.0, 0.0)),
             ExtraBone("Jaw", "head", (0.0, -0.05, 0.04)))
    frames, _ = _received_bones(extra, rest, frames=2)
    for bones in frames:
        assert list(bones) == [*UNITY_BONES, "LeftIndexProximal", "LeftIndexIntermediate", "Jaw"]
        for e in extra:
            np.testing.assert_allclose(bones[e.name][3:], [0, 0, 0, 1])
            np.testing.assert_allclose(position_from_unity(bones[e.name][:3]), e.offset, atol=1e-7)
        # The 22 still rebuild the pose sent (here the rest pose).
        pose = pose_from_vmc(bones)
        np.testing.assert_allclose(pose.rotations[:, 0], 1.0, atol=1e-7)


@pytest.mark.parametrize("bone", [("Tail", "pelvis"), ("LeftEye", "nose"), ("LeftIndexDistal", "LeftIndexProximal")])
def test_extra_bones_must_be_humanoid_and_hang_from_a_bone_sent(bone):
    from live.body.body import ExtraBone

    with pytest.raises(UserInputError):
        VmcSink(extra_bones=(ExtraBone(bone[0], bone[1], (0.0, 0.0, 0.0)),))


def test_godette_fingers_over_vmc_rebuild_her_own_rest_bones():
    """Godette's 24 finger bones arrive at rest after the 22; chained from her hands, the received
    localPositions put every finger bone where her file has it (1 mm), also split to fit an MTU."""
    from live.body.gltf_avatar import read_gltf_humanoid
    from live.core.assets import shared_data_dir
    from live.outputs.unity import UNITY_BONE_INDEX

    path = shared_data_dir() / "avatars" / "godette_vrm0.vrm"
    if not path.is_file():
        pytest.skip("../shared/data/avatars/godette_vrm0.vrm is absent")
    h = read_gltf_humanoid(path)
    body = h.body
    assert len(body.extra_bones) == 24
    for kwargs in ({}, {"max_bundle_bytes": 1400}):
        (bones,), sizes = _received_bones(body.extra_bones, body.rest_joints, **kwargs)
        assert len(bones) == 22 + 24 and max(sizes) <= kwargs.get("max_bundle_bytes", 65507)
        parent = {e.name: JOINT_TO_UNITY_BONE.get(e.parent, e.parent) for e in body.extra_bones}
        world = {}
        for e in body.extra_bones:  # parents first
            up = parent[e.name]
            at = world[up] if up in world else body.rest_joints[UNITY_BONE_INDEX[up]].astype(np.float64)
            np.testing.assert_allclose(bones[e.name][3:], [0, 0, 0, 1])
            world[e.name] = at + position_from_unity(bones[e.name][:3])
        # The file's own bone positions, in our frame (the file's scene -> ours: to_ours).
        vrm = {b: n for b, n in h.bones.items()}
        for e in body.extra_bones:
            node = vrm[e.name[0].lower() + e.name[1:]]
            want = h.to_ours[:3, :3] @ _node_world(path, node) + h.to_ours[:3, 3]
            np.testing.assert_allclose(world[e.name], want, atol=1e-3, err_msg=e.name)


def _node_world(path, node):
    """A node's world rest position from the GLB's JSON, summed by hand (Godette's nodes carry
    translations only)."""
    import json
    import struct

    data = path.read_bytes()
    (n,) = struct.unpack_from("<I", data, 12)
    doc = json.loads(data[20:20 + n])
    parent = {c: i for i, nd in enumerate(doc["nodes"]) for c in nd.get("children", [])}
    p, k = np.zeros(3), node
    while k is not None:
        assert doc["nodes"][k].get("rotation", [0, 0, 0, 1]) == [0, 0, 0, 1]
        p += doc["nodes"][k].get("translation", [0, 0, 0])
        k = parent.get(k)
    return p


def test_a_file_without_upper_chest_gets_its_chest_as_chest():
    """Godette has no upperChest: her chest bone is our spine3 (where the neck and arms branch off). With
    her rig, spine3's rotation goes out as Chest (once), nothing as UpperChest, spine2 (a point between
    her spine and chest, no bone of hers) as nothing; the default avatar keeps the 22 canonical bones."""
    from live.body.gltf_avatar import read_gltf_humanoid
    from live.core.assets import shared_data_dir
    from live.core.skeleton import JOINT_INDEX

    path = shared_data_dir() / "avatars" / "godette_vrm0.vrm"
    if not path.is_file():
        pytest.skip("../shared/data/avatars/godette_vrm0.vrm is absent")
    body = read_gltf_humanoid(path).body
    rot = np.tile([1.0, 0.0, 0.0, 0.0], (22, 1))
    turn = quat_from_axis_angle(np.array([0.3, 0.2, -0.1]))
    rot[JOINT_INDEX["spine3"]] = turn
    msgs = vmc_messages(body.rest_joints[0], rot, body.rest_joints, 0.0, rig=body.rig)
    bones = [args[0] for addr, args in msgs if addr == "/VMC/Ext/Bone/Pos"]
    assert bones.count("Chest") == 1 and "UpperChest" not in bones and len(bones) == len(set(bones))
    sent = {args[0]: np.array(args[4:8]) for addr, args in msgs if addr == "/VMC/Ext/Bone/Pos"}
    # Her bones are normalised (identity rest rotations): the chest's localRotation is spine3's own.
    np.testing.assert_allclose(sent["Chest"], quat_to_unity(turn), atol=1e-6)
    np.testing.assert_allclose(sent["Spine"], [0, 0, 0, 1], atol=1e-9)
    default = [args[0] for addr, args in vmc_messages(np.zeros(3), rot, body.rest_joints, 0.0)
               if addr == "/VMC/Ext/Bone/Pos"]
    assert default == list(UNITY_BONES)
