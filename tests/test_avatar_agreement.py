"""The demo take onto VRM avatars: avatar.npz, avatar.bvh and what a VMC receiver rebuilds on the
avatar's own skeleton agree (1 mm), for Godette (VRM 0.x, normalised bones, no upperChest), her
VRM 1.0 conversion (its root turned: every bone's rest rotation is a half turn) and a copy of it
whose every node has a rolled rest frame (as Blender exports have); the avatar faces the camera
and its left hand is on the performer's left.

The receiver here is independent of livecap's reader: it reads the file's JSON by hand, builds
the node tree in Unity's frame as UniVRM imports it (VRM 0.x: z reversed, VRM 1.0: x reversed),
sets every bone it is sent (localPosition and localRotation, as EVMC4U does) and runs forward
kinematics over the whole tree, nodes between bones at rest.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from pythonosc.osc_packet import OscPacket

from live.app.cli import main
from live.body.gltf_avatar import read_gltf_humanoid
from live.core.assets import shared_data_dir
from live.core.skeleton import JOINT_INDEX, JOINT_NAMES
from tests.glb_files import glb_chunks, write_glb
from tests.mirror_checks import assert_left_right_kept

GODETTE = shared_data_dir() / "avatars" / "godette_vrm0.vrm"
pytestmark = pytest.mark.skipif(not GODETTE.is_file(), reason="../shared/data/avatars/godette_vrm0.vrm is absent")
MM = 1e-3


# ----------------------------------------------------------------------------- files


def _quat_matrix(x, y, z, w) -> np.ndarray:
    n = np.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _matrix_quat(r: np.ndarray) -> list[float]:
    """(x, y, z, w) of a rotation matrix (Shepperd)."""
    t = np.trace(r)
    if t > 0:
        s = 2 * np.sqrt(1 + t)
        return [(r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, s / 4]
    i = int(np.argmax(np.diag(r)))
    j, k = (i + 1) % 3, (i + 2) % 3
    s = 2 * np.sqrt(1 + r[i, i] - r[j, j] - r[k, k])
    q = [0.0, 0.0, 0.0, 0.0]
    q[i], q[j], q[k], q[3] = s / 4, (r[j, i] + r[i, j]) / s, (r[k, i] + r[i, k]) / s, (r[k, j] - r[j, k]) / s
    return q


def _local(node: dict) -> np.ndarray:
    m = np.eye(4)
    if "matrix" in node:
        return np.array(node["matrix"], float).reshape(4, 4).T
    m[:3, :3] = _quat_matrix(*node.get("rotation", [0, 0, 0, 1])) @ np.diag(node.get("scale", [1, 1, 1]))
    m[:3, 3] = node.get("translation", [0, 0, 0])
    return m


def _parents(doc: dict) -> dict[int, int]:
    return {c: i for i, n in enumerate(doc["nodes"]) for c in n.get("children", [])}


def _world(doc: dict, locals_: list[np.ndarray]) -> list[np.ndarray]:
    parent = _parents(doc)
    out: list[np.ndarray | None] = [None] * len(locals_)

    def get(i: int) -> np.ndarray:
        if out[i] is None:
            out[i] = locals_[i] if i not in parent else get(parent[i]) @ locals_[i]
        return out[i]

    return [get(i) for i in range(len(locals_))]


def _sparse(src: Path, out: Path) -> Path:
    """A VRM 0.x copy mapping no neck, shoulders or toes (optional in VRM): those nodes stay in the
    tree as plain nodes, the joints become points between bones."""
    doc, blob = glb_chunks(src)
    drop = {"neck", "leftShoulder", "rightShoulder", "leftToes", "rightToes"}
    humanoid = doc["extensions"]["VRM"]["humanoid"]
    humanoid["humanBones"] = [b for b in humanoid["humanBones"] if b["bone"] not in drop]
    return write_glb(out, doc, blob)


def _rolled(src: Path, out: Path, seed: int = 0) -> Path:
    """A copy whose every node has its rest frame turned by a random rotation (its children's
    translations and the skin's inverse bind matrices compensated): the same mesh and skeleton,
    none of its bones with an identity rest rotation."""
    doc, blob = glb_chunks(src)
    rng = np.random.default_rng(seed)
    nodes = doc["nodes"]
    world = _world(doc, [_local(n) for n in nodes])
    turns = []
    for _ in nodes:
        q = rng.normal(size=4)
        turns.append(_quat_matrix(*q))
    new_world = []
    for w, r in zip(world, turns, strict=True):
        m = w.copy()
        m[:3, :3] = w[:3, :3] @ r
        new_world.append(m)
    parent = _parents(doc)
    for i, node in enumerate(nodes):
        loc = new_world[i] if i not in parent else np.linalg.inv(new_world[parent[i]]) @ new_world[i]
        for key in ("matrix", "rotation", "translation", "scale"):
            node.pop(key, None)
        node["translation"] = [float(v) for v in loc[:3, 3]]
        node["rotation"] = [float(v) for v in _matrix_quat(loc[:3, :3])]
    # Inverse bind matrices: the new joint frames' inverses (bound at rest, as before).
    data = bytearray(blob)
    for skin in doc.get("skins", []):
        acc = doc["accessors"][skin["inverseBindMatrices"]]
        view = doc["bufferViews"][acc["bufferView"]]
        start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
        for k, j in enumerate(skin["joints"]):
            ibm = np.linalg.inv(new_world[j]).T.astype("<f4")  # column-major
            data[start + 64 * k:start + 64 * (k + 1)] = ibm.tobytes()
    return write_glb(out, doc, bytes(data))


# ----------------------------------------------------------------------------- the VMC receiver


class _Receiver:
    """Every VMC bundle on a loopback port, decoded: a list of frames, each {bone: 7 values}."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.2)
        self.port = self.sock.getsockname()[1]
        self.frames: list[dict[str, tuple]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            for m in OscPacket(data).messages:
                msg = m.message
                if msg.address == "/VMC/Ext/OK":
                    self.frames.append({})
                elif msg.address == "/VMC/Ext/Bone/Pos":
                    name, *values = msg.params
                    assert name not in self.frames[-1], f"{name} sent twice in a frame"
                    self.frames[-1][name] = tuple(values)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.sock.close()


def _unity_name(bone: str) -> str:
    return bone[0].upper() + bone[1:]


def _receiver_joints(path: Path, frames: list[dict[str, tuple]]) -> tuple[dict[str, np.ndarray], list[str]]:
    """Per humanoid bone (Unity name), its world positions (T, 3) over the frames, the file's node tree
    posed by the received values in Unity's frame as UniVRM builds it. Also checks that each bone's
    received localPosition is the file's own (but the hips, which carry the motion)."""
    doc, _ = glb_chunks(path)
    ext = doc["extensions"]
    if "VRMC_vrm" in ext:
        bones = {_unity_name(b): v["node"] for b, v in ext["VRMC_vrm"]["humanoid"]["humanBones"].items()}
        flip = np.diag([-1.0, 1.0, 1.0, 1.0])  # UniVRM 1.0: x reversed
    else:
        bones = {_unity_name(b["bone"]): b["node"] for b in ext["VRM"]["humanoid"]["humanBones"]}
        flip = np.diag([1.0, 1.0, -1.0, 1.0])  # UniVRM 0.x: z reversed
    rest = [flip @ _local(n) @ flip for n in doc["nodes"]]
    out: dict[str, list[np.ndarray]] = {b: [] for b in bones}
    unknown: set[str] = set()
    for frame in frames:
        loc = list(rest)
        for name, v in frame.items():
            if name not in bones:
                unknown.add(name)
                continue
            n = bones[name]
            if name != "Hips":
                np.testing.assert_allclose(v[:3], rest[n][:3, 3], atol=1e-5, err_msg=name)
            m = np.eye(4)
            m[:3, :3] = _quat_matrix(*v[3:7])
            m[:3, 3] = v[:3]
            loc[n] = m
        world = _world(doc, loc)
        for b, n in bones.items():
            out[b].append(world[n][:3, 3])
    assert not unknown, f"bones the file does not have: {sorted(unknown)}"
    return {b: np.array(p) for b, p in out.items()}, sorted(frames[0])


# ----------------------------------------------------------------------------- the runs


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The demo onto each avatar with VMC to a loopback receiver: {kind: (avatar file, out folder, frames)}."""
    from research.vrm1_from_vrm0 import convert

    tmp = tmp_path_factory.mktemp("agreement")
    vrm1 = tmp / "godette_vrm1.vrm"
    convert(GODETTE, vrm1)
    files = {"vrm0": GODETTE, "vrm1": vrm1, "rolled": _rolled(vrm1, tmp / "godette_rolled.vrm"),
             "sparse": _sparse(GODETTE, tmp / "godette_sparse.vrm")}
    out = {}
    for kind, path in files.items():
        rx = _Receiver()
        try:
            # The files' mapping is checked, not the self-contacts (which move hands on each file's
            # own surface): --contacts off.
            code = main(["demo", "--avatar", str(path), "--no-video", "--out", str(tmp / kind), "--quiet",
                         "--vmc", f"127.0.0.1:{rx.port}", "--vmc-rate", "0", "--speed", "max", "--contacts", "off"])
            assert code == 0
            frames_expected = len(np.load(tmp / kind / "avatar.npz")["t_ns"])
            deadline = threading.Event()
            for _ in range(100):  # the last datagrams may still be in the receiver's socket
                if len(rx.frames) >= frames_expected:
                    break
                deadline.wait(0.05)
        finally:
            rx.close()
        out[kind] = (path, tmp / kind, rx.frames)
    return out


def _real_joints(path: Path) -> dict[int, str]:
    """Canonical joint -> Unity name of the file bone it is (the joints VMC drives)."""
    rig = read_gltf_humanoid(path).body.rig
    return {int(j): name for j, name in zip(rig.joint, rig.names, strict=False) if name in _BODY_BONES}


_BODY_BONES = {"Hips", "Spine", "Chest", "UpperChest", "Neck", "Head"} | {
    f"{s}{b}" for s in ("Left", "Right")
    for b in ("Shoulder", "UpperArm", "LowerArm", "Hand", "UpperLeg", "LowerLeg", "Foot", "Toes")}


#: Per file, the canonical joints that are none of its bones (points between bones).
_VIRTUAL = {"vrm0": {"spine2"}, "vrm1": {"spine2"}, "rolled": {"spine2"},
            "sparse": {"spine2", "neck", "left_collar", "right_collar", "left_foot", "right_foot"}}


@pytest.mark.parametrize("kind", ["vrm0", "vrm1", "rolled", "sparse"])
def test_vmc_receiver_rebuilds_avatar_npz_on_the_avatars_own_bones(runs, kind):
    path, out, frames = runs[kind]
    avatar = np.load(out / "avatar.npz")
    joints = avatar["joints"].astype(np.float64)
    assert len(frames) == len(joints) == 150
    h = read_gltf_humanoid(path)
    # Godette has no upperChest: her chest bone is our spine3 and goes out as Chest, once.
    names = set(frames[0])
    assert "Chest" in names and "UpperChest" not in names and len(names) == 22 - len(_VIRTUAL[kind]) + 24
    rebuilt, _ = _receiver_joints(path, frames)
    # Unity (the file's nodes, mirrored as UniVRM does) -> ours: the x mirror, then the lift to the floor.
    lift = h.to_ours[:3, 3]
    worst = 0.0
    real = _real_joints(path)
    assert {JOINT_NAMES[j] for j in range(22) if j not in real} == _VIRTUAL[kind]
    for j, bone in real.items():
        got = rebuilt[bone] * np.array([-1.0, 1.0, 1.0]) + lift
        err = np.linalg.norm(got - joints[:, j], axis=1).max()
        worst = max(worst, err)
        assert err < MM, f"{kind} {JOINT_NAMES[j]} ({bone}) off by {err * 1e3:.3f} mm"
    print(f"{kind}: VMC receiver vs avatar.npz, worst joint {worst * 1e3:.4f} mm")


@pytest.mark.parametrize("kind", ["vrm0", "vrm1", "rolled", "sparse"])
def test_bvh_forward_kinematics_is_avatar_npz(runs, kind):
    from live.io.bvh_kinematics import bvh_forward_kinematics
    from live.io.bvh_reader import read_bvh

    path, out, _ = runs[kind]
    avatar = np.load(out / "avatar.npz")
    clip = read_bvh(out / "avatar.bvh")
    assert abs(clip.frame_time - 1 / 15) < 1e-6
    pos = bvh_forward_kinematics(clip)[0]
    names = read_gltf_humanoid(path).body.joint_names
    order = [clip.skeleton.names.index(n) for n in names]
    err = np.linalg.norm(pos[:, order] - avatar["joints"], axis=-1).max()
    assert err < MM, err


def test_the_three_files_give_the_same_motion(runs):
    a = np.load(runs["vrm0"][1] / "avatar.npz")["joints"]
    for kind in ("vrm1", "rolled"):
        np.testing.assert_allclose(np.load(runs[kind][1] / "avatar.npz")["joints"], a, atol=MM)


def test_the_rolled_copy_sends_other_rotations_for_the_same_pose(runs):
    """Its bones' rest frames differ, so the same pose needs other local rotations (not a no-op)."""
    a, b = runs["vrm1"][2][40], runs["rolled"][2][40]
    diffs = [np.abs(np.subtract(a[n][3:], b[n][3:])).max() for n in a if n != "Hips"]
    assert min(diffs) > 1e-3


def test_the_avatar_faces_the_camera_and_mirrors_nothing(runs):
    _, out, _ = runs["vrm0"]
    avatar = np.load(out / "avatar.npz")["joints"].astype(np.float64)
    skel = np.load(out / "skeleton.npz")
    performer, cam = skel["joints"].astype(np.float64), skel["camera_to_world"][:, :3, 3]
    up = np.array([0.0, 1.0, 0.0])
    lh, rh = JOINT_INDEX["left_hip"], JOINT_INDEX["right_hip"]
    # Facing: (left - right) x up points where a body faces (ours: +x left, +y up, +z ahead).

    def facing(j: np.ndarray) -> np.ndarray:
        f = np.cross(j[:, lh] - j[:, rh], up)
        return f / np.linalg.norm(f, axis=1, keepdims=True)

    to_camera = cam - performer[:, 0]
    to_camera /= np.linalg.norm(to_camera, axis=1, keepdims=True)
    # The performer turns about during the take: the avatar turns with them, never mirrored.
    assert np.sum(facing(avatar) * facing(performer), 1).min() > 0.99
    towards = np.sum(facing(performer) * to_camera, 1) > 0.7
    assert towards.sum() > 20
    assert np.sum(facing(avatar)[towards] * to_camera[towards], 1).min() > 0.65
    assert_left_right_kept(avatar, performer)


# ----------------------------------------------------------------------------- Blender (optional)


_BLENDER_SCRIPT = r"""
import json, sys
import bpy
bvh, out = sys.argv[1], sys.argv[2]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_anim.bvh(filepath=bvh, global_scale=1.0, rotate_mode="NATIVE", axis_forward="-Z", axis_up="Y",
                        update_scene_fps=True, update_scene_duration=True, use_fps_scale=False)
scene = bpy.context.scene
arm = [o for o in scene.objects if o.type == "ARMATURE"][0]
frames = {}
start, end = (int(round(f)) for f in arm.animation_data.action.frame_range)
for f in range(start, end + 1):
    scene.frame_set(f)
    frames[f] = {b.name: list(arm.matrix_world @ b.head) for b in arm.pose.bones}
json.dump({"fps": scene.render.fps / scene.render.fps_base, "frames": frames}, open(out, "w"))
"""


def _blender_python() -> str | None:
    """A Python that imports bpy: this one, or $LIVECAP_BPY_PYTHON (bpy is never a livecap dependency)."""
    for python in (sys.executable, os.environ.get("LIVECAP_BPY_PYTHON")):
        if python and subprocess.run([python, "-c", "import bpy"], capture_output=True, timeout=120).returncode == 0:
            return python
    return None


@pytest.mark.parametrize("kind", ["vrm0", "rolled"])
def test_blender_imports_avatar_bvh_as_avatar_npz(runs, kind, tmp_path):
    python = _blender_python()
    if python is None:
        pytest.skip("no Python with bpy (pip install bpy into one; set LIVECAP_BPY_PYTHON)")
    path, out, _ = runs[kind]
    script = tmp_path / "import_bvh.py"
    script.write_text(_BLENDER_SCRIPT)
    result = tmp_path / "blender.json"
    subprocess.run([python, str(script), str(out / "avatar.bvh"), str(result)], check=True, capture_output=True,
                   timeout=600)
    got = json.loads(result.read_text())
    assert got["fps"] == pytest.approx(15.0)
    joints = np.load(out / "avatar.npz")["joints"]
    names = read_gltf_humanoid(path).body.joint_names
    frames = [got["frames"][k] for k in sorted(got["frames"], key=int)]
    assert len(frames) == len(joints)
    # Blender is z up: the importer took the BVH's (x, y, z) to (x, -z, y).
    pos = np.array([[frame[n] for n in names] for frame in frames])
    pos = np.stack([pos[..., 0], pos[..., 2], -pos[..., 1]], axis=-1)
    err = np.linalg.norm(pos - joints, axis=-1).max()
    assert err < MM, err
    print(f"{kind}: Blender's BVH import vs avatar.npz, worst joint {err * 1e3:.4f} mm")
