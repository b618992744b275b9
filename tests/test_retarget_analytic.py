"""Analytic retargeting: rotations from joints, copying onto other bodies, contacts and IK."""

import numpy as np
import pytest

from live.core import assets
from live.core.errors import UserInputError
from live.core.frames import GroundTruth, SkeletonFrame
from live.core.kinematics import forward_kinematics
from live.core.metrics import mpjpe
from live.core.rotations import quat_angle, quat_conjugate, quat_from_axis_angle, quat_multiply, quat_rotate
from live.core.skeleton import BONES, JOINT_INDEX, NUM_JOINTS, default_rest_joints, rest_offsets
from live.retarget.analytic import (
    LIMBS,
    RestInfo,
    estimate_rest_joints,
    leg_ratio,
    local_rotations_from_joints,
    retarget,
    solve_globals,
)
from live.retarget.contacts import FEET, ContactDetector, detect_contacts
from live.retarget.ik import two_bone_ik
from live.retarget.retargeter import AnalyticRetargeter, retarget_motion

BVH_DIR = assets.bvh_dir()
FPS = 30.0


def _smooth(rng, t, dims, amp):
    time = np.arange(t) / FPS
    out = np.zeros((t, dims))
    for _ in range(2):
        freq = rng.uniform(0.2, 1.2, dims)
        phase = rng.uniform(0, 2 * np.pi, dims)
        out += np.sin(2 * np.pi * freq * time[:, None] + phase) * amp / 2
    return out


def synth_motion(rng, rest, t=90):
    """Smooth plausible motion: 3-DOF joints within human-ish ranges, knees/elbows as hinges."""
    aa = np.zeros((t, NUM_JOINTS, 3))
    amp = {0: 0.3, 3: 0.25, 6: 0.25, 9: 0.25, 1: 0.5, 2: 0.5, 7: 0.3, 8: 0.3, 10: 0.2, 11: 0.2,
           12: 0.3, 15: 0.3, 13: 0.2, 14: 0.2, 16: 0.8, 17: 0.8, 20: 0.3, 21: 0.3}
    for j, a in amp.items():
        aa[:, j] = _smooth(rng, t, 3, a)
    aa[:, 0, 1] += _smooth(rng, t, 1, 2.0)[:, 0]  # turning
    for limb in LIMBS:
        bend = np.clip(0.8 + _smooth(rng, t, 1, 1.4)[:, 0], 0.0, 2.0)
        aa[:, limb[1]] = np.array(limb[3]) * bend[:, None]
    root = np.zeros((t, 3))
    root[:, [0, 2]] = np.cumsum(_smooth(rng, t, 2, 0.05), axis=0)
    root[:, 1] = rest[0, 1] + _smooth(rng, t, 1, 0.05)[:, 0]
    return quat_from_axis_angle(aa), root


def perturbed_body(rng, height):
    """default_rest_joints(height) with bones rescaled +-10 % and turned up to 3 degrees."""
    base = default_rest_joints(height).astype(np.float64)
    off = rest_offsets(base)
    out = base.copy()
    for p, c in BONES:
        axis = rng.normal(size=3)
        q = quat_from_axis_angle(axis / np.linalg.norm(axis) * np.deg2rad(rng.uniform(0, 3)))
        out[c] = out[p] + quat_rotate(q, off[c]) * rng.uniform(0.9, 1.1)
    feet = FEET.ravel()
    out[:, 1] -= out[feet, 1].min() - base[feet, 1].min()
    return out


# --- rotations from joints ---------------------------------------------------------------


@pytest.mark.parametrize("height", [1.2, 1.75, 2.0])
def test_fk_of_recovered_rotations_reproduces_joints(height):
    rng = np.random.default_rng(int(height * 10))
    rest = default_rest_joints(height)
    rot = quat_from_axis_angle(rng.normal(scale=0.6, size=(50, NUM_JOINTS, 3)))  # any 3-DOF pose
    joints, _ = forward_kinematics(rot, rng.normal(size=(50, 3)), rest)
    rec = local_rotations_from_joints(joints, rest)
    assert rec.shape == (50, NUM_JOINTS, 4)
    again, _ = forward_kinematics(rec, joints[:, 0], rest)
    assert mpjpe(again, joints) < 1e-6
    # Leaves carry no observable twist: identity.
    leaves = [JOINT_INDEX[n] for n in ("left_foot", "right_foot", "head", "left_wrist", "right_wrist")]
    np.testing.assert_allclose(np.abs(rec[:, leaves, 0]), 1.0, atol=1e-9)


def test_hinges_and_root_orientation_are_recovered():
    rng = np.random.default_rng(11)
    rest = default_rest_joints()
    rot, root = synth_motion(rng, rest, t=120)
    joints, _ = forward_kinematics(rot, root, rest)
    rec = local_rotations_from_joints(joints, rest)
    err = np.rad2deg(quat_angle(quat_multiply(quat_conjugate(rec), rot)))
    assert err[:, 0].max() < 1e-6  # pelvis: fully observed from hips and spine
    assert err[:, JOINT_INDEX["spine3"]].max() < 45  # carries the spine twist, see docs
    # Knees and elbows are hinges: recovered within a few degrees wherever the limb is bent.
    for _, mid, _, _ in LIMBS:
        bent = quat_angle(rot[:, mid]) > np.deg2rad(20)
        assert np.median(err[bent, mid]) < 3.0


def test_batch_equals_frame_by_frame():
    rng = np.random.default_rng(12)
    rest = default_rest_joints(1.6)
    rot, root = synth_motion(rng, rest, t=40)
    joints, _ = forward_kinematics(rot, root, rest)
    info = RestInfo.of(rest)
    _, batch, twist_b = solve_globals(joints, info)
    twist = None
    for t in range(len(joints)):
        _, single, twist = solve_globals(joints[t : t + 1], info, twist)
        np.testing.assert_allclose(single[0], batch[t], atol=1e-12)
    np.testing.assert_allclose(twist, twist_b, atol=1e-12)


def test_straight_limb_keeps_previous_twist():
    rest = default_rest_joints()
    t = 30
    aa = np.zeros((t, NUM_JOINTS, 3))
    knee = JOINT_INDEX["left_knee"]
    hip = JOINT_INDEX["left_hip"]
    aa[:, hip, 1] = 0.4  # thigh turned inwards: visible only while the knee is bent
    aa[:, knee, 0] = np.where(np.arange(t) < 15, 1.0, 0.0)  # bent, then straight
    rot = quat_from_axis_angle(aa)
    joints, _ = forward_kinematics(rot, np.tile(rest[0], (t, 1)), rest)
    rec = local_rotations_from_joints(joints, rest)
    # Once straight, the hip keeps the twist seen while bent instead of snapping to zero twist.
    assert np.rad2deg(quat_angle(quat_multiply(quat_conjugate(rec[-1, hip]), rot[-1, hip]))) < 1.0


def test_bad_shapes_raise_user_input_error():
    with pytest.raises(UserInputError):
        local_rotations_from_joints(np.zeros((3, 21, 3)), default_rest_joints())
    with pytest.raises(UserInputError):
        AnalyticRetargeter(default_rest_joints(), default_rest_joints()).step(np.zeros((22, 4)))


# --- moving motion between bodies ----------------------------------------------------------


def test_retarget_copies_rotations_and_scales_root():
    a, b = default_rest_joints(1.8), default_rest_joints(1.5)
    rot = quat_from_axis_angle(np.random.default_rng(0).normal(size=(4, NUM_JOINTS, 3)))
    root = np.array([[1.0, 0.9, -2.0]] * 4)
    r2, root2 = retarget(rot, root, a, b)
    np.testing.assert_array_equal(r2, rot)
    assert leg_ratio(a, b) == pytest.approx(1.5 / 1.8)
    np.testing.assert_allclose(root2, root * 1.5 / 1.8)


@pytest.mark.parametrize("seed", [21, 22, 23])
def test_retarget_to_held_out_bodies_within_10mm(seed):
    rng = np.random.default_rng(seed)
    src = perturbed_body(rng, rng.uniform(1.5, 1.95))
    dst = perturbed_body(rng, rng.uniform(1.1, 2.0))
    rot, root = synth_motion(rng, src, t=90)
    joints, _ = forward_kinematics(rot, root, src)
    truth, _ = forward_kinematics(rot, root * leg_ratio(src, dst), dst)
    _, _, plain = retarget_motion(src, dst, joints=joints, fps=FPS, foot_lock=False, floor=False)
    assert mpjpe(plain, truth) < 0.010
    _, _, locked = retarget_motion(src, dst, joints=joints, fps=FPS)
    assert mpjpe(locked, truth) < 0.030  # locking and floor clearance move the legs on purpose


def test_rotation_input_matches_joint_input():
    rng = np.random.default_rng(31)
    src, dst = default_rest_joints(1.7), perturbed_body(rng, 1.6)
    rot, root = synth_motion(rng, src, t=30)
    joints, _ = forward_kinematics(rot, root, src)
    _, _, from_joints = retarget_motion(src, dst, joints=joints, foot_lock=False, floor=False)
    r_root, r_rot, from_rot = retarget_motion(src, dst, rotations=rot, root=root, foot_lock=False, floor=False)
    truth, _ = forward_kinematics(rot, root * leg_ratio(src, dst), dst)
    np.testing.assert_allclose(from_rot, truth, atol=1e-9)
    assert mpjpe(from_joints, truth) < 0.005
    fk, _ = forward_kinematics(r_rot, r_root, dst)
    np.testing.assert_allclose(fk, from_rot, atol=1e-9)


def test_process_frames_and_reset():
    rng = np.random.default_rng(41)
    src, dst = default_rest_joints(1.7), default_rest_joints(1.3)
    rot, root = synth_motion(rng, src, t=20)
    joints, _ = forward_kinematics(rot, root, src)
    rt = AnalyticRetargeter(src, dst)
    poses = [rt.process(SkeletonFrame(t_ns=i * 33_333_333, joints=j, confidence=np.ones(22))) for i, j in enumerate(joints)]
    rt.reset()
    again = [rt.process(SkeletonFrame(t_ns=i * 33_333_333, joints=j, confidence=np.ones(22))) for i, j in enumerate(joints)]
    for p, q in zip(poses, again):
        np.testing.assert_array_equal(p.joints, q.joints)
    fk, _ = forward_kinematics(poses[-1].rotations, poses[-1].root, dst)
    np.testing.assert_allclose(fk, poses[-1].joints, atol=1e-9)
    gt_pose = rt.process(GroundTruth(t_ns=10**9, joints=joints[0], rotations=rot[0], root=root[0]))
    assert gt_pose.rotations.shape == (22, 4) and gt_pose.root.shape == (3,)


# --- contacts, locking, floor, IK ------------------------------------------------------------


def _sway(rest, t=60, amplitude=0.04, dip=0.04):
    """Stiff legs, pelvis swaying sideways: the source's feet slide with the pelvis."""
    rot = np.zeros((t, NUM_JOINTS, 4))
    rot[..., 0] = 1.0
    root = np.tile(rest[0].astype(np.float64), (t, 1))
    root[:, 0] += amplitude * np.sin(np.linspace(0, 2 * np.pi, t))
    root[:, 1] -= dip
    return forward_kinematics(rot, root, rest)[0]


def test_contact_detector_hysteresis_scales_with_body():
    for height in (1.0, 1.9):
        rest = default_rest_joints(height)
        leg = rest[0, 1]
        det = ContactDetector(rest)
        ankles = rest[FEET[:, 0]].astype(np.float64).copy()
        assert det.update(ankles, 1 / FPS).all()  # standing still on the floor
        lifted = ankles + [0.0, 0.065 * leg, 0.0]  # between the on and off heights
        assert det.update(lifted, 1.0).all()  # kept (hysteresis), moving slowly
        assert not det.update(lifted + [0.0, 0.05 * leg, 0.0], 1.0).any()  # above off height
        assert not det.update(lifted, 1.0).any()  # not low enough to start again
        assert not det.update(ankles, 1 / FPS).any()  # low but fast
        assert det.update(ankles, 1 / FPS).all()  # low and still


def test_foot_lock_holds_sliding_feet_still():
    rest = default_rest_joints(1.7)
    joints = _sway(rest)
    contacts = detect_contacts(joints, rest, FPS)
    assert contacts.all()
    _, _, free = retarget_motion(rest, rest, joints=joints, fps=FPS, foot_lock=False)
    _, _, held = retarget_motion(rest, rest, joints=joints, fps=FPS, foot_lock=True, blend_frames=4, soft_ik=0.0)
    ankles = FEET[:, 0]
    assert np.ptp(free[:, ankles, 0], axis=0).min() > 0.05
    assert np.abs(held[5:, ankles] - held[5, ankles]).max() < 1e-6
    # The default soft IK eases the nearly straight legs of this sway: held to within a millimetre.
    _, _, soft = retarget_motion(rest, rest, joints=joints, fps=FPS, foot_lock=True, blend_frames=4)
    assert np.abs(soft[5:, ankles] - soft[5, ankles]).max() < 1e-3
    # Everything above the legs is untouched, and bone lengths are kept.
    np.testing.assert_allclose(held[:, [0, 3, 6, 9, 12, 15]], free[:, [0, 3, 6, 9, 12, 15]], atol=1e-9)
    lengths = np.linalg.norm(held[:, 4] - held[:, 1], axis=-1)
    np.testing.assert_allclose(lengths, np.linalg.norm(rest[4] - rest[1]), rtol=1e-6)


def test_no_foot_goes_below_the_floor():
    rest = default_rest_joints(1.6)
    joints = _sway(rest, amplitude=0.0, dip=0.10)  # straight legs pushed 10 cm into the floor
    feet = FEET.ravel()
    assert joints[:, feet, 1].min() < -0.05
    _, _, out = retarget_motion(rest, rest, joints=joints, foot_lock=False, floor=True)
    assert out[:, feet, 1].min() > -1e-9
    # The knees bent forward to absorb it.
    assert np.all(out[:, JOINT_INDEX["left_knee"], 2] > joints[:, JOINT_INDEX["left_knee"], 2] + 0.05)


def test_two_bone_ik_reaches_and_keeps_lengths():
    rng = np.random.default_rng(51)
    a = rng.normal(size=(100, 3))
    b = a + rng.normal(size=(100, 3)) * 0.4
    c = b + rng.normal(size=(100, 3)) * 0.4
    reach = np.linalg.norm(b - a, axis=-1) + np.linalg.norm(c - b, axis=-1)
    short = np.abs(np.linalg.norm(b - a, axis=-1) - np.linalg.norm(c - b, axis=-1))
    direction = rng.normal(size=(100, 3))
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    dist = rng.uniform(short + 0.05 * reach, 0.95 * reach)
    target = a + direction * dist[:, None]
    up, low = two_bone_ik(a, b, c, target, np.tile([1.0, 0, 0], (100, 1)))
    b2 = a + np.einsum("nij,nj->ni", up, b - a)
    c2 = b2 + np.einsum("nij,nj->ni", low, c - b)
    np.testing.assert_allclose(c2, target, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(b2 - a, axis=-1), np.linalg.norm(b - a, axis=-1), atol=1e-12)
    # Straight leg, target above the foot: the knee bends forward (+z) about the hint.
    up, low = two_bone_ik(np.array([0, 1.0, 0]), np.array([0, 0.5, 0]), np.zeros(3), np.array([0, 0.2, 0]), np.array([1.0, 0, 0]))
    assert (up @ np.array([0, -0.5, 0]))[2] > 0.1


def test_soft_ik_keeps_the_knee_from_snapping_past_the_reach():
    from live.retarget.ik import limb_ik, soft_reach

    # soft_reach: exact up to (1 - soft) x reach, then below the reach with a continuous slope.
    assert soft_reach(0.9, 1.0, 0.05) == 0.9
    d = np.linspace(0.9, 1.3, 4001)
    eased = np.array([soft_reach(x, 1.0, 0.05) for x in d])
    assert np.all(np.diff(eased) > 0) and eased.max() < 1.0
    assert abs(soft_reach(0.95 + 1e-6, 1.0, 0.05) - (0.95 + 1e-6)) < 1e-11  # slope 1 at the joint
    # A hip pulled up away from a planted ankle, past the leg's reach (two ~0.5 m bones):
    # exact IK snaps the knee straight within the last millimetres, soft IK eases it there.
    hip, knee, ankle = [0.0, 1.0, 0.0], [0.0, 0.5, 0.03], [0.0, 0.0, 0.0]
    hint = [-1.0, 0.0, 0.0]
    for soft, limit in ((0.0, None), (0.05, 0.002)):
        knees = []
        for y in np.linspace(0.95, 1.05, 201):  # target below the hip by y: 2 cm past the reach
            upper, _ = limb_ik(hip, knee, ankle, [0.0, 1.0 - y, 0.0], hint, soft)
            knees.append(np.array(hip) + np.array(upper) @ (np.array(knee) - hip))
        steps = np.linalg.norm(np.diff(knees, axis=0), axis=-1)  # per 0.5 mm of target motion
        if limit is None:
            assert steps.max() > 0.005  # millimetres of knee for half a millimetre of target
        else:
            assert steps.max() < limit


def test_hand_ik_reaches_scaled_source_hands():
    rng = np.random.default_rng(61)
    src = default_rest_joints(1.75)
    dst = default_rest_joints(1.4).astype(np.float64)
    off = rest_offsets(dst)
    off[18:22] *= 1.15  # upper arms and forearms 15 % longer than the leg-length ratio predicts
    for p, c in BONES:
        dst[c] = dst[p] + off[c]
    rot, root = synth_motion(rng, src, t=30)
    joints, _ = forward_kinematics(rot, root, src)
    r_root, _, out = retarget_motion(src, dst, joints=joints, hand_ik=True, foot_lock=False, floor=False)
    wrists = [JOINT_INDEX["left_wrist"], JOINT_INDEX["right_wrist"]]
    want = r_root[:, None] + (joints[:, wrists] - joints[:, :1]) * leg_ratio(src, dst)
    sh = [JOINT_INDEX["left_shoulder"], JOINT_INDEX["right_shoulder"]]
    arm = np.linalg.norm(dst[18] - dst[16]) + np.linalg.norm(dst[20] - dst[18])
    reachable = np.linalg.norm(want - out[:, sh], axis=-1) < 0.95 * arm
    assert reachable.mean() > 0.5
    np.testing.assert_allclose(out[:, wrists][reachable], want[reachable], atol=1e-6)
    # Without hand IK the longer arms overshoot.
    _, _, free = retarget_motion(src, dst, joints=joints, foot_lock=False, floor=False)
    assert np.linalg.norm(free[:, wrists] - want, axis=-1).mean() > 0.02


def test_estimate_rest_joints_from_posed_motion():
    rng = np.random.default_rng(71)
    rest = default_rest_joints(1.62)
    rot, root = synth_motion(rng, rest, t=30)
    joints, _ = forward_kinematics(rot, root, rest)
    est = estimate_rest_joints(joints, default_rest_joints())  # the template it was built on
    np.testing.assert_allclose(est, rest, atol=1e-5)


def test_real_clip_round_trip():
    rig_mapping = pytest.importorskip("live.motion.rig_mapping")
    clips = sorted(BVH_DIR.glob("*.bvh"))
    if not clips:
        pytest.skip("no BVH clips in ../shared/data/bvh")
    motion = rig_mapping.load_motion(clips[1])
    joints = np.asarray(motion.joints[:120], dtype=np.float64)
    rec = local_rotations_from_joints(joints, motion.rest_joints)
    again, _ = forward_kinematics(rec, joints[:, 0], motion.rest_joints)
    assert mpjpe(again, joints) < 1e-3
    dst = default_rest_joints(1.4)
    truth, _ = forward_kinematics(motion.rotations[:120], motion.root[:120] * leg_ratio(motion.rest_joints, dst), dst)
    _, _, plain = retarget_motion(motion.rest_joints, dst, joints=joints, fps=motion.fps, foot_lock=False, floor=False)
    assert mpjpe(plain, truth) < 0.010


def test_performer_rest_estimate_with_library_template():
    """A library body's T-pose estimated from its posed joints with the other bodies' mean
    T-pose as bone-direction template keeps its pelvis height within 3 % (the straight-leg
    default template makes it several per cent taller)."""
    from live.body.library import list_presets, load_body, mean_rest_template
    from live.core.skeleton import pelvis_height

    names = list_presets()
    if len(names) < 3:
        pytest.skip("no body library")
    body = load_body(names[0])
    template = mean_rest_template(tuple(names[1:]))
    rng = np.random.default_rng(5)
    rot, root = synth_motion(rng, np.asarray(body.rest_joints, np.float64), t=20)
    joints, _ = forward_kinematics(rot, root, np.asarray(body.rest_joints, np.float64))
    true = pelvis_height(body.rest_joints)
    assert abs(pelvis_height(estimate_rest_joints(joints, template)) / true - 1) < 0.03
    assert pelvis_height(estimate_rest_joints(joints, default_rest_joints())) / true > 1.03
