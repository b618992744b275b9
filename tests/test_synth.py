"""Synthetic sessions: ground truth matches the BVH, rendered points lie on the body, same seed
same bytes, and the session replays like a recorded one."""

import numpy as np
import pytest

from live.body.library import load_body
from live.core.skeleton import JOINT_INDEX as J
from live.io.session import SessionReader
from live.motion.clips import resample
from live.motion.rig_mapping import load_motion
from sim.synth import CameraPlacement, SyntheticScene, SynthOptions, synthesize

FLEXIONS = [("left_hip", "left_knee", "left_ankle"), ("right_hip", "right_knee", "right_ankle"),
            ("left_shoulder", "left_elbow", "left_wrist"), ("right_shoulder", "right_elbow", "right_wrist")]


def flexion_deg(joints):
    out = []
    for a, b, c in FLEXIONS:
        u = joints[:, J[a]] - joints[:, J[b]]
        v = joints[:, J[c]] - joints[:, J[b]]
        cos = (u * v).sum(-1) / np.linalg.norm(u, axis=-1) / np.linalg.norm(v, axis=-1)
        out.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    return np.stack(out, -1)


def test_ground_truth_keeps_joint_angles_of_every_clip(shared_bvh):
    body = load_body("short_heavy_female")
    worst = 0.0
    for clip in sorted(shared_bvh.glob("*.bvh")):
        motion = load_motion(clip)
        scene = SyntheticScene.build(motion, body, camera="oak-d", fps=30)
        source = resample(motion, 30).joints
        worst = max(worst, float(np.abs(flexion_deg(scene.joints) - flexion_deg(source)).max()))
    assert worst < 3.0


def test_rendered_points_lie_on_the_body(shared_bvh):
    import open3d as o3d

    from live.core.depth import depth_to_points, points_to_world
    from sim.depth_camera import NoiseModel

    scene = SyntheticScene.build(load_motion(shared_bvh / "cc_002_01.bvh"), load_body("performer"),
                                 noise=NoiseModel.none(), placement=CameraPlacement(2.5, 1.3, 0.4))
    i = 40
    verts = scene.vertices(i)
    depth, mask = scene.camera.render_with_labels(verts, scene.body.faces)
    body_depth = np.where(mask, depth, 0).astype(np.uint16)
    pts = points_to_world(depth_to_points(body_depth, scene.camera.intrinsics), scene.camera.camera_to_world)
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(o3d.core.Tensor(verts.astype(np.float32)), o3d.core.Tensor(scene.body.faces.astype(np.uint32)))
    dist = rc.compute_distance(o3d.core.Tensor(pts.astype(np.float32))).numpy()
    assert len(pts) > 2000 and np.median(dist) < 0.02


def test_same_seed_same_bytes_and_replayable(tmp_path, shared_bvh):
    opts = SynthOptions(motion=str(shared_bvh / "cc_002_01.bvh"), body="child_girl_6y", seconds=0.5, seed=3)
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    synthesize(opts, a)
    synthesize(opts, b)
    assert a.read_bytes() == b.read_bytes()
    reader = SessionReader(a)
    kinds = [s.kind for s, _ in reader.frames()]
    assert kinds.count("depth") == 15 and kinds.count("gt") == 15 and reader.error is None
    assert reader.body_npz() is not None
    other = SynthOptions(motion=opts.motion, body=opts.body, seconds=0.5, seed=4)
    synthesize(other, tmp_path / "c.mcap")
    assert (tmp_path / "c.mcap").read_bytes() != a.read_bytes()


def _world_points(depth, c2w):
    from live.core.depth import depth_to_points, points_to_world

    return points_to_world(depth_to_points(depth.depth_mm, depth.intrinsics), c2w)


def test_hidden_extrinsics_keep_the_image_and_tell_the_pose_only_to_the_truth(tmp_path, shared_bvh):
    from live.core.frames import DepthFrame

    opts = SynthOptions(motion=str(shared_bvh / "mb_16_31.bvh"), body="short_male", seconds=0.2, fps=15, seed=2,
                        placement=CameraPlacement(2.0, 0.7, 0.5, np.radians(30)))
    told, hidden = tmp_path / "told.mcap", tmp_path / "hidden.mcap"
    synthesize(opts, told)
    synthesize(SynthOptions(**{**opts.__dict__, "hide_extrinsics": True}), hidden)
    frames = {}
    for path in (told, hidden):
        reader = SessionReader(path)
        frames[path] = [f for _, f in reader.frames() if isinstance(f, DepthFrame)]
        streams = {s.kind: s for s in reader.info.streams}
    true_c2w = np.asarray(frames[told][0].camera_to_world)
    assert np.array_equal(np.asarray(streams["gt"].meta["camera_to_world"]), true_c2w)
    assert np.array_equal(np.asarray(streams["depth"].meta["camera_to_world"]), np.eye(4))
    for a, b in zip(frames[told], frames[hidden]):
        assert np.array_equal(a.depth_mm, b.depth_mm) and np.array_equal(b.camera_to_world, np.eye(4))
    # Pitched 30 degrees down from 0.7 m: the camera looks down (world forward y < 0).
    assert true_c2w[1, 2] == pytest.approx(-0.5)


def test_floor_none_returns_no_floor_depth(shared_bvh):
    motion = load_motion(shared_bvh / "mb_12_01.bvh")
    placement = CameraPlacement(2.5, 1.5, 0.0, np.radians(25))
    counts = []
    for floor in (True, False):
        scene = SyntheticScene.build(motion, load_body("short_male"), fps=15, placement=placement, floor=floor,
                                     posture="in-place")
        pts = _world_points(scene.depth(5, 0), scene.camera.camera_to_world)
        far = np.hypot(pts[:, 0] - scene.joints[5, 0, 0], pts[:, 2] - scene.joints[5, 0, 2]) > 0.8
        inside = (np.abs(pts[:, 0]) < scene.room.width / 2 - 0.3) & (np.abs(pts[:, 2]) < scene.room.depth / 2 - 0.3)
        counts.append(int(((np.abs(pts[:, 1]) < 0.05) & far & inside).sum()))  # floor, not walls or feet
    assert counts[0] > 20000 and counts[1] == 0


def test_postures_stay_in_place_sit_on_a_chair_and_crouch(shared_bvh):
    motion = load_motion(shared_bvh / "mb_08_07.bvh")
    body = load_body("teen_girl_14y")
    scenes = {p: SyntheticScene.build(motion, body, fps=15, posture=p) for p in ("clip", "in-place", "seated", "crouching")}
    travel = {p: np.ptp(s.joints[:, J["pelvis"], 2]) for p, s in scenes.items()}
    assert travel["clip"] > 2.0 and max(travel["in-place"], travel["seated"], travel["crouching"]) < 0.3
    pelvis = {p: np.median(s.joints[:, J["pelvis"], 1]) for p, s in scenes.items()}
    assert pelvis["crouching"] < pelvis["seated"] < pelvis["in-place"] - 0.2
    seated = scenes["seated"].joints
    assert np.abs(seated[:, J["left_knee"], 1] - seated[:, J["left_hip"], 1]).max() < 0.03  # thighs level
    feet = seated[:, [J["left_ankle"], J["right_ankle"]], 1]
    assert feet.max() < 0.15  # on the floor
    seat, back = scenes["seated"].room.boxes
    assert seat.size[1] < seated[:, J["left_hip"], 1].min() and not scenes["crouching"].room.boxes


def test_knee_up_raises_each_knee_in_turn_toward_where_the_body_faces(shared_bvh):
    from live.core.heading import body_heading
    from sim.postures import KNEE_UP_PERIOD_S, knee_raise

    left, right = knee_raise(np.array([0.25, 0.5, 0.75, 1.25]) * KNEE_UP_PERIOD_S)
    assert left.tolist() == pytest.approx([1.0, 0.0, 0.0, 1.0]) and right.tolist() == pytest.approx([0.0, 0.0, 1.0, 0.0])
    motion = load_motion(shared_bvh / "mb_08_07.bvh")
    scene = SyntheticScene.build(motion, load_body("teen_girl_14y"), fps=30, posture="knee-up")
    j = scene.joints
    assert np.ptp(j[:, J["pelvis"], 2]) < 0.3  # in place
    up = {side: j[:, J[f"{side}_knee"], 1] - j[:, J[f"{side}_hip"], 1] for side in ("left", "right")}
    t = np.arange(len(j)) / 30.0
    peak_left, peak_right = (np.abs(t % KNEE_UP_PERIOD_S - f * KNEE_UP_PERIOD_S) < 0.02 for f in (0.25, 0.75))
    assert up["left"][peak_left].min() > -0.05 and up["right"][peak_left].max() < -0.3  # left thigh level
    assert up["right"][peak_right].min() > -0.05 and up["left"][peak_right].max() < -0.3
    knee_ahead = j[:, J["left_knee"]] - j[:, J["left_hip"]]
    facing = body_heading(j)
    ahead = knee_ahead[:, 0] * np.sin(facing) + knee_ahead[:, 2] * np.cos(facing)
    assert ahead[peak_left].min() > 0.3  # the raised knee is in front of the body
    feet = j[:, [J["left_ankle"], J["right_ankle"]], 1].min(axis=1)
    assert feet.max() < 0.15  # one foot stays on the floor



def test_kick_swings_each_leg_straight_out_in_front_at_the_top(shared_bvh):
    from live.core.heading import body_heading
    from sim.postures import KICK_HIP_DEG, KNEE_UP_PERIOD_S

    motion = load_motion(shared_bvh / "mb_08_07.bvh")
    scene = SyntheticScene.build(motion, load_body("teen_girl_14y"), fps=30, posture="kick")
    j = scene.joints
    t = np.arange(len(j)) / 30.0
    facing = body_heading(j)
    for side, f in (("left", 0.25), ("right", 0.75)):
        top = np.abs(t % KNEE_UP_PERIOD_S - f * KNEE_UP_PERIOD_S) < 0.02
        half = np.abs(t % KNEE_UP_PERIOD_S - (f - 0.125) * KNEE_UP_PERIOD_S) < 0.02
        hip, knee, ankle = (j[:, J[f"{side}_{p}"]] for p in ("hip", "knee", "ankle"))
        thigh, shin = knee - hip, ankle - knee
        cos = np.sum(thigh * shin, axis=1) / np.linalg.norm(thigh, axis=1) / np.linalg.norm(shin, axis=1)
        bend = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        assert bend[top].max() < 5 and bend[half].min() > 45  # straight at the top, chambered on the way
        leg = ankle - hip
        ahead = leg[:, 0] * np.sin(facing) + leg[:, 2] * np.cos(facing)
        assert ahead[top].min() > 0.6 * np.linalg.norm(leg[top], axis=1).min()  # pointing ahead
        lift = np.degrees(np.arctan2(leg[top, 1], ahead[top]))
        assert np.all(np.abs(lift - (KICK_HIP_DEG - 90)) < 12)  # about KICK_HIP_DEG from hanging
    assert j[:, [J["left_ankle"], J["right_ankle"]], 1].min(axis=1).max() < 0.15  # one foot down

def test_synth_command_pitch_posture_floor_and_hidden_extrinsics(tmp_path, shared_bvh):
    from live.app.cli import main

    out = tmp_path / "s.mcap"
    assert main(["synth", "--motion", str(shared_bvh / "mb_16_31.bvh"), "--out", str(out), "--seconds", "0.2",
                 "--fps", "15", "--height", "2.3", "--pitch", "-40", "--posture", "crouching", "--floor", "none",
                 "--hide-extrinsics", "--quiet"]) == 0
    reader = SessionReader(out)
    gt = next(s for s in reader.info.streams if s.kind == "gt")
    c2w = np.asarray(gt.meta["camera_to_world"])
    assert c2w[1, 3] == pytest.approx(2.3) and c2w[1, 2] == pytest.approx(-np.sin(np.radians(40)))
    assert main(["synth", "--motion", str(shared_bvh / "mb_16_31.bvh"), "--out", str(out), "--pitch", "90"]) == 2
