"""VRM and glTF humanoid avatars (live/body/gltf_avatar.py): the file's own skeleton, skin and facing."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from live.app.cli import main
from live.body.gltf_avatar import read_gltf_humanoid
from live.core.assets import shared_data_dir
from live.core.skeleton import JOINT_INDEX, JOINT_NAMES
from tests.glb_files import glb_chunks, write_glb
from tests.mirror_checks import assert_left_right_kept

GODETTE = shared_data_dir() / "avatars" / "godette_vrm0.vrm"
needs_godette = pytest.mark.skipif(not GODETTE.is_file(), reason="../shared/data/avatars/godette_vrm0.vrm is absent")


def _file_bone_positions() -> dict[str, np.ndarray]:
    """World rest position of each humanoid bone, summed along the node tree by hand (Godette's nodes
    carry translations only: checked)."""
    doc, _ = glb_chunks(GODETTE)
    parent = {c: i for i, n in enumerate(doc["nodes"]) for c in n.get("children", [])}
    out = {}
    for b in doc["extensions"]["VRM"]["humanoid"]["humanBones"]:
        p, k = np.zeros(3), b["node"]
        while k is not None:
            node = doc["nodes"][k]
            assert "matrix" not in node and node.get("rotation", [0, 0, 0, 1]) == [0, 0, 0, 1]
            p += node.get("translation", [0, 0, 0])
            k = parent.get(k)
        out[b["bone"]] = p
    return out


@needs_godette
def test_godette_rest_joints_are_the_files_own_bones():
    h = read_gltf_humanoid(GODETTE)
    assert h.kind == "vrm0" and h.turned  # VRM 0.x faces -z
    bones = _file_bone_positions()
    rest = h.body.rest_joints.astype(np.float64)
    node_to_bone = {h.bones[b]: b for b in h.bones}
    # Our frame: turned half about y, then shifted to the floor (compared relative to the hips).
    turn = np.diag([-1.0, 1.0, -1.0])
    checked = 0
    for i, name in enumerate(JOINT_NAMES):
        src = h.joint_sources[i]
        if src is None:
            continue
        want = turn @ (bones[node_to_bone[src]] - bones["hips"])
        np.testing.assert_allclose(rest[i] - rest[0], want, atol=1e-3, err_msg=name)
        checked += 1
    assert checked == 21  # all but spine2 (Godette has no upperChest: it lies between spine and chest)
    # Her spine bone sits on her hips, and so does spine1: the rig turns her own bones.
    s2 = rest[JOINT_INDEX["spine2"]]
    assert np.linalg.norm(rest[JOINT_INDEX["spine1"]] - rest[0]) < 1e-3
    assert rest[0, 1] < s2[1] < rest[JOINT_INDEX["spine3"]][1]
    rig = h.body.rig
    assert rig.virtual.nonzero()[0].tolist() == [JOINT_INDEX["spine2"]]
    assert rig.names[:3] == ("Hips", "LeftUpperLeg", "RightUpperLeg") and "Chest" in rig.names
    assert "UpperChest" not in rig.names
    np.testing.assert_allclose(rig.rest, np.tile([1.0, 0, 0, 0], (len(rig.names), 1)), atol=1e-9)  # normalised


@needs_godette
def test_godette_faces_plus_z_left_hand_at_plus_x():
    b = read_gltf_humanoid(GODETTE).body
    j = b.rest_joints
    for side, sign in (("left", 1), ("right", -1)):
        assert sign * j[JOINT_INDEX[f"{side}_wrist"], 0] > 0.3
        assert j[JOINT_INDEX[f"{side}_foot"], 2] > j[JOINT_INDEX[f"{side}_ankle"], 2] + 0.03  # toes ahead
    # The face is in front of the head: vertices near head height reach further in +z than in -z
    # behind it is the hair and the backpack, so compare at the eyes' height, in the middle.
    v = b.vertices
    head = j[JOINT_INDEX["head"]]
    face = v[(np.abs(v[:, 0]) < 0.05) & (np.abs(v[:, 1] - head[1] - 0.15) < 0.05)]
    assert face[:, 2].max() - head[2] > 0.15
    assert abs(float(v[:, 1].min())) < 1e-6  # feet on the floor
    assert np.allclose(b.weights.sum(1), 1.0, atol=1e-5) and (b.weights >= 0).all()
    assert len(b.faces) > 3000 and b.faces.max() < len(v)


@needs_godette
def test_vrm1_conversion_gives_the_same_body(tmp_path):
    from research.vrm1_from_vrm0 import convert

    out = tmp_path / "godette_vrm1.vrm"
    convert(GODETTE, out)
    doc, _ = glb_chunks(out)
    assert "VRMC_vrm" in doc["extensions"] and "VRM" not in doc["extensions"]
    a, b = read_gltf_humanoid(GODETTE), read_gltf_humanoid(out)
    assert b.kind == "vrm1" and not b.turned
    np.testing.assert_allclose(b.body.rest_joints, a.body.rest_joints, atol=1e-3)
    np.testing.assert_allclose(b.body.vertices, a.body.vertices, atol=1e-3)
    np.testing.assert_allclose(b.body.weights, a.body.weights, atol=1e-5)
    assert b.body.joint_names == a.body.joint_names


def _extra(body) -> dict:
    return {e.name: (e.parent, np.asarray(e.offset)) for e in body.extra_bones}


@needs_godette
def test_vrm1_thumb_names_give_the_same_extra_bones(tmp_path):
    """VRM 1.0 names the thumb one step earlier (Metacarpal, Proximal, Distal): renamed so, the
    file gives the same HumanBodyBones thumbs, parents and offsets as VRM 0.x's names."""
    from research.vrm1_from_vrm0 import convert

    out = tmp_path / "godette_vrm1.vrm"
    convert(GODETTE, out)
    doc, blob = glb_chunks(out)
    bones = doc["extensions"]["VRMC_vrm"]["humanoid"]["humanBones"]
    for side in ("left", "right"):
        prox, inter = bones.pop(f"{side}ThumbProximal"), bones.pop(f"{side}ThumbIntermediate")
        bones[f"{side}ThumbMetacarpal"], bones[f"{side}ThumbProximal"] = prox, inter
    renamed = write_glb(tmp_path / "thumbs_vrm1.vrm", doc, blob)
    want = _extra(read_gltf_humanoid(GODETTE).body)
    assert len(want) == 24 and want["LeftThumbIntermediate"][0] == "LeftThumbProximal"
    for path in (out, renamed):
        got = _extra(read_gltf_humanoid(path).body)
        assert got.keys() == want.keys()
        for name, (parent, offset) in want.items():
            assert got[name][0] == parent
            np.testing.assert_allclose(got[name][1], offset, atol=1e-5, err_msg=name)


@needs_godette
def test_plain_skin_maps_by_bone_names(tmp_path):
    """Without the VRM extension the skin's bone names still give the skeleton (spine joints apart)."""
    doc, blob = glb_chunks(GODETTE)
    del doc["extensions"]["VRM"]
    doc["extensionsUsed"].remove("VRM")
    h = read_gltf_humanoid(write_glb(tmp_path / "skin.glb", doc, blob))
    ref = read_gltf_humanoid(GODETTE).body.rest_joints
    assert h.kind == "skin"
    limbs = [i for i, n in enumerate(JOINT_NAMES) if n.startswith(("left_", "right_")) or n in ("neck", "head")]
    np.testing.assert_allclose(h.body.rest_joints[limbs], ref[limbs], atol=1e-3)


@needs_godette
def test_demo_onto_godette(tmp_path, capsys):
    """The demo take onto Godette, VRM 0.x and her VRM 1.0 conversion: the same poses, finite, her
    left side on the performer's left."""
    from research.vrm1_from_vrm0 import convert

    vrm1 = tmp_path / "godette_vrm1.vrm"
    convert(GODETTE, vrm1)
    joints = []
    for name, avatar_file, bvh_names in (("vrm0", GODETTE, "avatar"), ("vrm1", vrm1, "canonical")):
        out = tmp_path / name
        # The mapping of the two files, not the self-contacts (which move the hands): --contacts off.
        assert main(["demo", "--avatar", str(avatar_file), "--no-video", "--out", str(out), "--quiet",
                     "--bvh-names", bvh_names, "--contacts", "off"]) == 0
        avatar = np.load(out / "avatar.npz")
        assert avatar["joints"].shape[0] > 100 and np.isfinite(avatar["joints"]).all()
        np.testing.assert_allclose(avatar["rest_joints"], read_gltf_humanoid(GODETTE).body.rest_joints, atol=1e-6)
        joints.append(avatar["joints"])
    np.testing.assert_allclose(joints[1], joints[0], atol=1e-3)
    _check_bvh_names(tmp_path)
    performer = np.load(tmp_path / "vrm0" / "skeleton.npz")["joints"]
    assert_left_right_kept(joints[0], performer)


def _check_bvh_names(tmp_path: Path) -> None:
    """avatar.bvh under Godette's own bone nodes (the canonical names with --bvh-names canonical):
    the same motion as the canonical BVH of the same avatar.npz, joint for joint."""
    from live.io.bvh_kinematics import bvh_forward_kinematics
    from live.io.bvh_reader import read_bvh
    from live.io.bvh_writer import write_canonical_bvh

    h = read_gltf_humanoid(GODETTE)
    own = read_bvh(tmp_path / "vrm0" / "avatar.bvh")
    assert set(read_bvh(tmp_path / "vrm1" / "avatar.bvh").skeleton.names) == set(JOINT_NAMES)
    expected = {JOINT_NAMES[j]: h.node_names[node] for j, node in enumerate(h.joint_sources) if node is not None}
    assert expected["pelvis"] == "pelvis_Armature" and len(expected) >= 20
    a = np.load(tmp_path / "vrm0" / "avatar.npz")
    write_canonical_bvh(tmp_path / "canonical.bvh", a["rotations"], a["root"], a["rest_joints"], 15.0)
    canonical = read_bvh(tmp_path / "canonical.bvh")
    by_canonical = dict(zip(canonical.skeleton.names, own.skeleton.names, strict=True))
    assert all(by_canonical[j] == n for j, n in expected.items())
    assert all(by_canonical[j] == j for j in JOINT_NAMES if j not in expected)
    np.testing.assert_allclose(bvh_forward_kinematics(own)[0], bvh_forward_kinematics(canonical)[0], atol=1e-6)


def _cli_error(tmp_path, capsys, avatar: Path) -> str:
    assert main(["demo", "--avatar", str(avatar), "--no-video", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    return err[0]


def test_text_file_named_vrm(tmp_path, capsys):
    bad = tmp_path / "bad.vrm"
    bad.write_text("this is not an avatar\n")
    assert "not a glTF file" in _cli_error(tmp_path, capsys, bad)


@needs_godette
def test_glb_without_vrm_and_skin(tmp_path, capsys):
    doc, blob = glb_chunks(GODETTE)
    del doc["extensions"]["VRM"]
    doc["extensionsUsed"].remove("VRM")
    doc.pop("skins")
    for node in doc["nodes"]:
        node.pop("skin", None)
    line = _cli_error(tmp_path, capsys, write_glb(tmp_path / "mesh.vrm", doc, blob))
    assert "no VRM humanoid and no skin" in line


@needs_godette
def test_vrm_missing_a_required_bone(tmp_path, capsys):
    doc, blob = glb_chunks(GODETTE)
    bones = doc["extensions"]["VRM"]["humanoid"]["humanBones"]
    doc["extensions"]["VRM"]["humanoid"]["humanBones"] = [b for b in bones if b["bone"] != "leftLowerArm"]
    line = _cli_error(tmp_path, capsys, write_glb(tmp_path / "no_elbow.vrm", doc, blob))
    assert "lacks required bones: leftLowerArm" in line


@needs_godette
def test_broken_buffer(tmp_path, capsys):
    doc, blob = glb_chunks(GODETTE)
    line = _cli_error(tmp_path, capsys, write_glb(tmp_path / "cut.vrm", doc, blob[:len(blob) // 2]))
    assert "bytes" in line


def _mesh_only(tmp_path: Path, source: Path, name: str) -> Path:
    doc, blob = glb_chunks(source)
    for key in ("VRM", "VRMC_vrm"):
        doc["extensions"].pop(key, None)
        if key in doc.get("extensionsUsed", []):
            doc["extensionsUsed"].remove(key)
    doc.pop("skins")
    for node in doc["nodes"]:
        node.pop("skin", None)
    return write_glb(tmp_path / name, doc, blob)


@needs_godette
def test_mesh_only_glb_keeps_the_skinning_field_path_and_faces_plus_z(tmp_path, capsys):
    """A .glb with neither a VRM humanoid nor a skin is a plain T-pose mesh: skeleton fitted, field
    weights, its materials kept. Godette's mesh faces -z (VRM 0.x): her feet say so and she is
    turned half about y, exactly as her rigged file is (not mirrored: her left hand at +x); her VRM
    1.0 conversion's mesh faces +z and is kept."""
    from live.body.avatar import facing_measure, load_avatar
    from live.body.skinning_field import DEFAULT_MODEL
    from research.vrm1_from_vrm0 import convert

    if not DEFAULT_MODEL.is_file():
        pytest.skip("no committed skinning_field.onnx")
    rigged = read_gltf_humanoid(GODETTE).body
    left_hand = rigged.weights[:, JOINT_INDEX["left_wrist"]] > 0.5
    vrm1 = tmp_path / "vrm1.vrm"
    convert(GODETTE, vrm1)
    for source, name in ((GODETTE, "minus_z.glb"), (vrm1, "plus_z.glb")):
        body = load_avatar(_mesh_only(tmp_path, source, name))
        assert body.rest_joints.shape == (22, 3) and np.allclose(body.weights.sum(1), 1.0, atol=1e-4)
        assert facing_measure(body.vertices) > 0.03
        # The same vertices as the rigged reading's, up to where the figure is centred.
        shift = (body.vertices - rigged.vertices).mean(0)
        np.testing.assert_allclose(body.vertices, rigged.vertices + shift, atol=1e-4, err_msg=name)
        assert body.vertices[left_hand, 0].min() > 0.3
        assert body.look is not None and len(body.look.face_material) == len(body.faces)
    assert capsys.readouterr().err == ""


def test_a_figure_without_feet_says_it_takes_plus_z(capsys):
    from live.body.avatar import face_plus_z, facing_measure

    angle, height = np.meshgrid(np.linspace(0, 2 * np.pi, 48, endpoint=False), np.linspace(0, 1.7, 120))
    column = np.stack([0.2 * np.cos(angle), height, 0.2 * np.sin(angle)], -1).reshape(-1, 3)  # a round post
    assert abs(facing_measure(column)) < 0.01
    np.testing.assert_array_equal(face_plus_z(column, "column.ply"), column)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "column.ply" in err[0] and "+z" in err[0]


@needs_godette
def test_a_pose_is_posed_into_the_t_pose(tmp_path):
    """Godette's upper arms turned 40 degrees down (an A-pose): the arms come back out sideways,
    bone lengths kept, and her mesh comes with them through her own skin."""
    import math

    doc, blob = glb_chunks(GODETTE)
    half = math.radians(40) / 2
    for node in doc["nodes"]:
        if node["name"] in ("upper_arm.l_Armature", "upper_arm.r_Armature"):
            sign = 1 if ".l" in node["name"] else -1  # VRM 0.x: her left arm points along -x
            node["rotation"] = [0, 0, sign * math.sin(half), math.cos(half)]
    t_pose = read_gltf_humanoid(GODETTE).body
    posed = read_gltf_humanoid(write_glb(tmp_path / "a_pose.vrm", doc, blob)).body
    j, ref = posed.rest_joints.astype(np.float64), t_pose.rest_joints.astype(np.float64)
    for side in ("left", "right"):
        sh, el, wr = (JOINT_INDEX[f"{side}_{n}"] for n in ("shoulder", "elbow", "wrist"))
        arm = j[wr] - j[sh]
        assert abs(arm[1]) < 1e-3 * np.linalg.norm(arm)  # horizontal
        for a, b in ((sh, el), (el, wr)):
            assert abs(np.linalg.norm(j[b] - j[a]) - np.linalg.norm(ref[b] - ref[a])) < 1e-4
    # Her own rest arms droop about 2 degrees: the straightened ones differ from them by ~1.5 cm.
    assert np.abs(posed.vertices - t_pose.vertices).max() < 0.03


@needs_godette
@pytest.mark.parametrize("field, value", [(("accessors", 0, "count"), "many"), (("nodes", 5, "children"), [[1]]),
                                          (("skins", 0, "joints"), None), (("accessors", 2, "bufferView"), 999)])
def test_malformed_fields_are_one_line(tmp_path, capsys, field, value):
    doc, blob = glb_chunks(GODETTE)
    target = doc
    for key in field[:-1]:
        target = target[key]
    target[field[-1]] = value
    line = _cli_error(tmp_path, capsys, write_glb(tmp_path / "malformed.vrm", doc, blob))
    assert "malformed.vrm" in line


@needs_godette
def test_gltf_json_with_a_bin_file_beside_it(tmp_path, capsys):
    doc, blob = glb_chunks(GODETTE)
    doc["buffers"][0]["uri"] = "godette.bin"
    (tmp_path / "godette.bin").write_bytes(blob)
    (tmp_path / "godette.gltf").write_text(json.dumps(doc))
    b = read_gltf_humanoid(tmp_path / "godette.gltf").body
    np.testing.assert_array_equal(b.rest_joints, read_gltf_humanoid(GODETTE).body.rest_joints)
    # A buffer naming a file outside the glTF's folder is refused, never read.
    doc["buffers"][0]["uri"] = "../godette.bin"
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "escape.gltf").write_text(json.dumps(doc))
    assert "not a file beside the glTF" in _cli_error(tmp_path, capsys, tmp_path / "sub" / "escape.gltf")
