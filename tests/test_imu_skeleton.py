"""Suit layout, calibration and suit -> skeleton, on exact constructions and a real clip."""

import json
from pathlib import Path

import numpy as np
import pytest

from live.core.errors import FormatError, UserInputError
from live.core.frames import MocapPacket
from live.core.heading import yaw_of, yaw_quat
from live.core.kinematics import forward_kinematics, global_rotations, joints_from_global_quats, local_rotations
from live.core.rotations import quat_angle, quat_conjugate, quat_multiply
from live.core.skeleton import JOINT_INDEX, default_rest_joints, rest_offsets
from live.imu.calibration import Calibration, CalibrationCollector, calibrate, pose_globals
from live.imu.layout import load_suit_layout
from live.imu.stage import ImuSkeletonStage, build_stages
from live.imu.suit_skeleton import ChainPlan, fill_globals
from live.io.session import SessionReader
from live.motion.clips import resample
from live.motion.rig_mapping import load_motion
from live.pipeline.runner import Pipeline
from sim.imu_model import random_rotations
from sim.imu_stream import MotionScene, write_suit_session
from sim.replay import ReplaySource

REST = default_rest_joints(1.68)


def _packets(layout, quats, t0=0, n=50):
    """n identical packets (t0 + 10 ms steps) carrying quats (S, 4) in layout order."""
    return [MocapPacket(t_ns=t0 + k * 10_000_000, device="suit", sensors=layout.sensors.copy(),
                        quats=np.asarray(quats, np.float32)) for k in range(n)]


def test_layout_files_partial_suits_and_mounting(tmp_path: Path):
    full = load_suit_layout(None)
    assert full.size == 15 and JOINT_INDEX["spine3"] in full.joints
    obj = {"name": "upper", "sensors": {"3": "chest", "7": "left_forearm", "9": "pelvis"},
           "mounting": {"7": [0.0, 0.0, 1.0, 0.0]}}
    p = tmp_path / "upper.json"
    p.write_text(json.dumps(obj))
    lay = load_suit_layout(p)
    assert lay.sensors.tolist() == [3, 7, 9]
    assert lay.joints.tolist() == [JOINT_INDEX["spine3"], JOINT_INDEX["left_elbow"], 0]
    np.testing.assert_allclose(lay.mounting[1], [0, 0, 1, 0])
    assert load_suit_layout(lay.to_json()).as_dict() == lay.as_dict()
    with pytest.raises(FormatError):
        load_suit_layout({"sensors": {"1": "pelvis", "2": "pelvis"}})
    with pytest.raises(FormatError):
        load_suit_layout({"sensors": {"1": "pelvis"}, "mounting": {"1": [0, 0, 0]}})
    with pytest.raises(UserInputError):
        load_suit_layout(tmp_path / "missing.json")


@pytest.mark.parametrize("pose", ["tpose", "npose"])
def test_calibration_recovers_segment_rotations_exactly(pose):
    layout = load_suit_layout(None)
    rng = np.random.default_rng(0)
    A = yaw_quat(0.9)  # sensor world heading x performer facing, unknown to the calibration
    M = layout.mounting  # mounting = the nominal pockets: the heading vote is then exact
    P = pose_globals(pose, REST)[layout.joints]
    cal = calibrate(_packets(layout, quat_multiply(quat_multiply(A, P), M)), layout, pose, REST)
    np.testing.assert_allclose(quat_angle(quat_multiply(quat_conjugate(cal.segment_globals(
        quat_multiply(quat_multiply(A, P), M))), P)), 0, atol=1e-6)
    G = random_rotations(layout.size, rng)
    got = cal.segment_globals(quat_multiply(quat_multiply(A, G), M))
    assert np.degrees(quat_angle(quat_multiply(quat_conjugate(got), G))).max() < 1e-3
    again = Calibration.from_json(json.loads(json.dumps(cal.to_json())))
    np.testing.assert_allclose(again.offset, cal.offset)


def test_calibration_tolerates_mounting_errors_by_averaging_the_heading():
    layout = load_suit_layout(None)
    rng = np.random.default_rng(1)
    from live.core.rotations import quat_from_axis_angle

    M = quat_from_axis_angle(rng.normal(0, np.radians(10), (layout.size, 3)))
    A = yaw_quat(-2.0)
    cal = calibrate(_packets(layout, quat_multiply(A, M)), layout, "tpose", REST)
    G = random_rotations(layout.size, rng)
    got = cal.segment_globals(quat_multiply(quat_multiply(A, G), M))
    assert np.degrees(quat_angle(quat_multiply(quat_conjugate(got), G))).mean() < 8.0


def test_calibration_refuses_motion_and_silent_sensors():
    layout = load_suit_layout(None)
    still = np.tile([1.0, 0, 0, 0], (layout.size, 1))
    moving = _packets(layout, still, n=5) + _packets(layout, quat_multiply(yaw_quat(np.full(layout.size, 0.6)), still), n=5)
    with pytest.raises(UserInputError, match="moved"):
        calibrate(moving, layout)
    partial = [MocapPacket(0, "suit", sensors=layout.sensors[:3], quats=still[:3].astype(np.float32))]
    with pytest.raises(UserInputError, match="no samples"):
        calibrate(partial, layout)


def test_collector_waits_for_the_hold():
    layout = load_suit_layout(None)
    still = np.tile([1.0, 0, 0, 0], (layout.size, 1))
    col = CalibrationCollector(layout, hold_s=1.0)
    assert all(col.feed(p) is None for p in _packets(layout, still, n=60))  # 0.59 s only
    results = [col.feed(p) for p in _packets(layout, still, t0=600_000_000, n=50)]
    assert results[-1] is None or isinstance(results[-1], Calibration)
    assert any(isinstance(r, Calibration) for r in results)


def test_fill_globals_and_fast_fk_match_forward_kinematics():
    layout = load_suit_layout(None)
    plan = ChainPlan.of(layout.joints)
    rng = np.random.default_rng(2)
    seg = random_rotations(layout.size, rng)
    glob = fill_globals(seg, plan)
    np.testing.assert_allclose(glob[layout.joints], seg * np.sign(np.sum(glob[layout.joints] * seg, -1))[:, None],
                               atol=1e-9)
    local = local_rotations(glob)
    ref, ref_glob = forward_kinematics(local, np.array([0.1, 0.9, 0.2]), REST)
    offsets = rest_offsets(REST.astype(np.float64))
    np.testing.assert_allclose(joints_from_global_quats(glob, np.array([0.1, 0.9, 0.2]), offsets), ref, atol=1e-9)
    # Spine1 and spine2 split the pelvis -> chest rotation in equal thirds.
    rel = quat_multiply(quat_conjugate(glob[0]), glob[JOINT_INDEX["spine3"]])
    third = quat_angle(quat_multiply(quat_conjugate(glob[0]), glob[JOINT_INDEX["spine1"]]))
    assert third == pytest.approx(quat_angle(rel) / 3, rel=1e-6)
    assert np.allclose(global_rotations(local), glob, atol=1e-9) or np.allclose(
        np.abs(np.sum(global_rotations(local) * glob, -1)), 1.0, atol=1e-9)


@pytest.fixture(scope="module")
def walk_session(tmp_path_factory, shared_bvh):
    motion = resample(load_motion(shared_bvh / "cc_002_05.bvh"), 30.0)
    scene = MotionScene.of(motion, REST)
    path = tmp_path_factory.mktemp("imu") / "walk.mcap"
    write_suit_session(path, scene, seed=3, frames=300)
    return path, scene


def _run_imu(path, scene, **kw):
    meta = next(s.meta for s in SessionReader(path).info.streams if s.kind == "serial")
    stage = build_stages("imu", stream_meta=meta, **kw)[0]
    # The performer starts on a marked spot, facing a marked direction.
    stage.world_yaw = float(yaw_of(scene.motion.rotations[0, 0]))
    stage.start = scene.root[0]
    pairs = []
    Pipeline([ReplaySource(path)], [stage], mode="every",
             on_result=lambda r: pairs.append((r.skeleton.joints, r.truth.joints))
             if r.depth is not None and r.skeleton is not None else None).run()
    pred = np.array([p for p, _ in pairs], np.float64)
    gt = np.array([g for _, g in pairs], np.float64)
    return stage, pred, gt


def test_imu_only_skeleton_matches_ground_truth(walk_session):
    path, scene = walk_session
    stage, pred, gt = _run_imu(path, scene, rest_joints=REST)
    assert isinstance(stage, ImuSkeletonStage) and stage.calibration is not None
    assert len(pred) == 300
    mpjpe = np.linalg.norm(pred - gt, axis=-1).mean()
    rel = np.linalg.norm((pred - pred[:, :1]) - (gt - gt[:, :1]), axis=-1).mean()
    assert rel < 0.04 and mpjpe < 0.06, (rel, mpjpe)


def test_partial_suit_still_poses_the_skeleton(walk_session, tmp_path):
    path, scene = walk_session
    layout = {"name": "lower+trunk", "sensors": {"1": "pelvis", "2": "chest", "10": "left_thigh",
                                                 "11": "left_shin", "13": "right_thigh", "14": "right_shin"}}
    _, pred, gt = _run_imu(path, scene, rest_joints=REST, layout=layout)
    legs = [JOINT_INDEX[n] for n in ("left_knee", "right_knee", "left_ankle", "right_ankle")]
    err = np.linalg.norm((pred - pred[:, :1]) - (gt - gt[:, :1]), axis=-1)
    assert err[:, legs].mean() < 0.03
