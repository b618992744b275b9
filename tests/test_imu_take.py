"""Calibration from the take itself (live.imu.take_calibration) and the heading guard against
magnetic disturbance (live.imu.heading_guard), on a simulated suit walking (cc_007_04)."""

from __future__ import annotations

import numpy as np
import pytest

from live.core.frames import MocapPacket
from live.core.heading import yaw_of, yaw_quat
from live.core.kinematics import forward_kinematics
from live.core.rotations import quat_multiply, quat_normalize
from live.core.skeleton import JOINT_INDEX as J
from live.imu.calibration import calibrate
from live.imu.layout import load_suit_layout
from live.imu.suit_skeleton import SuitSolver
from live.imu.take_calibration import facing_from_motion, find_still, take_mounting

RATE = 60.0


@pytest.fixture(scope="module")
def suit_walk(shared_bvh):
    """A 15-sensor suit with random mountings on a performer holding an N-pose for 1.2 s, then
    walking: sensor orientations (T, S, 4), times, layout, motion."""
    from live.motion.cleaning import trim_bind_pose
    from live.motion.clips import resample
    from live.motion.rig_mapping import load_motion
    from sim.imu_model import SimpleMotion, random_mounting, simulate_imus
    from sim.imu_stream import calibration_prelude

    m = resample(trim_bind_pose(load_motion(shared_bvh / "cc_007_04.bvh")), RATE)
    pre = calibration_prelude(m.rotations[0], "npose", m.rest_joints, 1.2, 0.3, RATE)
    rot = np.concatenate([pre, m.rotations]).astype(np.float64)
    root = np.concatenate([np.broadcast_to(m.root[0], (len(pre), 3)), m.root])
    layout = load_suit_layout(None)
    motion = SimpleMotion(RATE, rot, root, np.asarray(m.rest_joints, np.float64))
    track = simulate_imus(motion, layout.as_dict(), mounting=random_mounting(layout.size, 5))
    return {"q": track.quats, "t": np.arange(len(rot)) / RATE, "layout": layout, "rot": rot, "root": root,
            "rest": motion.rest_joints, "hold": 1.2, "mounting": track.mounting}


def test_find_still_finds_the_hold_and_nothing_in_motion(suit_walk):
    q, t = suit_walk["q"], suit_walk["t"]
    i0, i1 = find_still(q, t)
    assert i0 == 0 and suit_walk["hold"] - 0.3 < t[i1] <= suit_walk["hold"]
    assert find_still(q[int(2 * RATE):], t[int(2 * RATE):]) is None  # walking: no hold


def test_facing_from_walking_aligns_every_sensor_whatever_its_mounting(suit_walk):
    q, t, layout = suit_walk["q"], suit_walk["t"], suit_walk["layout"]
    still = find_still(q, t)
    facing = facing_from_motion(q, t, layout.joints, still)
    truth = float(yaw_of(suit_walk["rot"][0, 0]))
    legs = [i for i, j in enumerate(layout.joints) if facing.method[i] == "hinge"]
    assert len(legs) == 6  # thighs, shanks, feet
    err = np.degrees(np.abs(np.angle(np.exp(1j * (facing.yaw[legs] - truth)))))
    feet = np.isin(layout.joints[legs], [J["left_ankle"], J["right_ankle"]])
    assert err[~feet].max() < 5 and err[feet].max() < 15, err  # an ankle's axis is oblique
    # The nominal mountings make calibration exact: the legs' bones as the motion has them.
    mount = take_mounting(q, layout.joints, still, facing, "npose", suit_walk["rest"])
    packets = [MocapPacket(t_ns=int(k * 1e9 / RATE), device="s", sensors=layout.sensors, quats=q[k])
               for k in range(still[0], still[1] + 1)]
    from live.imu.layout import SuitLayout

    suit = SuitLayout(layout.name, layout.sensors, layout.joints, mount)
    cal = calibrate(packets, suit, "npose", suit_walk["rest"], per_sensor_heading=True)
    solver = SuitSolver(cal, suit_walk["rest"], world_yaw=truth, heading_guard=False)
    truth_joints, _ = forward_kinematics(suit_walk["rot"], suit_walk["root"], suit_walk["rest"])
    leg_joints = [J[f"{s}_{n}"] for s in ("left", "right") for n in ("knee", "ankle", "foot")]
    errs = []
    for k in range(int(2 * RATE), len(q), 5):
        pose = solver.solve(q[k])
        rel = pose.joints - pose.joints[J["left_hip"]]
        true_rel = truth_joints[k] - truth_joints[k, J["left_hip"]]
        errs.append(np.linalg.norm(rel[leg_joints] - true_rel[leg_joints], axis=-1).mean())
    assert np.mean(errs) < 0.03, np.mean(errs)


def _legs_error(q, suit_walk, cal, guard: bool) -> float:
    truth, _ = forward_kinematics(suit_walk["rot"], suit_walk["root"], suit_walk["rest"])
    solver = SuitSolver(cal, suit_walk["rest"], world_yaw=float(yaw_of(suit_walk["rot"][0, 0])), heading_guard=guard)
    legs = [J[f"{s}_{n}"] for s in ("left", "right") for n in ("ankle", "foot")]
    errs = []
    for k in range(len(q)):
        pose = solver.solve(q[k], t_ns=int(k * 1e9 / RATE))
        if suit_walk["t"][k] > 2.5:
            rel, true_rel = pose.joints - pose.joints[:1], truth[k] - truth[k, :1]
            errs.append(np.linalg.norm(rel[legs] - true_rel[legs], axis=-1).mean())
    return float(np.mean(errs))


def test_heading_guard_pulls_a_magnetically_disturbed_sensor_back(suit_walk):
    q, t, layout = suit_walk["q"].copy(), suit_walk["t"], suit_walk["layout"]
    packets = [MocapPacket(t_ns=int(k * 1e9 / RATE), device="s", sensors=layout.sensors, quats=q[k])
               for k in range(int(RATE))]
    from live.imu.layout import SuitLayout

    # The pockets' true mountings as the nominal ones: an exact calibration, the guard alone tested.
    suit = SuitLayout(layout.name, layout.sensors, layout.joints, suit_walk["mounting"])
    cal = calibrate(packets, suit, "npose", suit_walk["rest"], per_sensor_heading=True)
    clean = _legs_error(q, suit_walk, cal, guard=True)
    # From 1.5 s the right shank's and the left foot's headings drift 35 deg away (a steel floor).
    disturbed = q.copy()
    drift = np.radians(35.0) * np.clip((t - 1.5) / 0.5, 0.0, 1.0)
    for name in ("right_knee", "left_ankle"):
        s = list(layout.joints).index(J[name])
        disturbed[:, s] = quat_normalize(quat_multiply(yaw_quat(drift), disturbed[:, s]))
    without = _legs_error(disturbed, suit_walk, cal, guard=False)
    with_guard = _legs_error(disturbed, suit_walk, cal, guard=True)
    assert with_guard < 0.7 * without, (with_guard, without)
    assert clean < 0.02  # and it costs little without a disturbance
