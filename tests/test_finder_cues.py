"""The person finder's cues against clutter: flat faces, walls for up without a floor, and a first
pick of still clutter giving way to the performer who moves."""

from __future__ import annotations

import numpy as np
import pytest

from live.core.frames import DepthFrame
from live.core.rotations import angle_deg
from live.core.skeleton import BONES, JOINT_INDEX, default_rest_joints
from models.skeleton.ground import LEVEL_UP, find_wall
from models.skeleton.person_clusters import find_person_cluster, plane_share, wall_inliers
from models.skeleton.preprocess import PersonFinder
from models.skeleton.preprocess_config import PreprocessConfig
from sim.depth_camera import NoiseModel, VirtualDepthCamera, look_at_camera
from sim.room import Room, capsule_body, capsule_mesh, merge_meshes

JOINTS = default_rest_joints(1.75).astype(np.float64)


def test_a_box_face_is_flat_and_a_person_is_not():
    rng = np.random.default_rng(1)
    face = np.stack([rng.uniform(-0.25, 0.25, 800), rng.uniform(0.0, 1.7, 800), rng.normal(0.0, 0.005, 800)])
    assert plane_share(face.astype(np.float32), 0.03) > 0.95
    # The camera-facing half of the capsule person.
    verts = capsule_body(JOINTS)[0]
    front = verts[verts[:, 2] > np.median(verts[:, 2])]
    assert plane_share(front.T.astype(np.float32), 0.03) < 0.7
    assert plane_share(face[:, :5].astype(np.float32), 0.03) == 0.0  # too few points to say


def _wall_points(pitch_deg: float, yaw_deg: float = 0.0, width: float = 6.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame points of a wall 3 m ahead (turned by yaw) seen from a camera pitched by
    pitch_deg, and the true up in camera axes."""
    rng = np.random.default_rng(seed)
    u, v = rng.uniform(-width / 2, width / 2, 4000), rng.uniform(0.0, 2.6, 4000)
    yaw = np.radians(yaw_deg)
    world = np.stack([u * np.cos(yaw), v, -3.0 + u * np.sin(yaw)], axis=1) + rng.normal(0, 0.004, (4000, 3))
    p = np.radians(pitch_deg)
    # Camera 1.5 m high looking along -z, pitched up by p: world = R cam + t.
    forward = np.array([0.0, np.sin(p), -np.cos(p)])
    right = np.array([1.0, 0.0, 0.0])
    down = np.cross(forward, right)
    rot = np.stack([right, down, forward], axis=1)
    cam = (world - [0.0, 1.5, 0.0]) @ rot
    return cam, rot.T @ np.array([0.0, 1.0, 0.0])


def test_a_wall_ahead_gives_the_pitch_of_a_camera_without_floor():
    for pitch, yaw in ((-25.0, 0.0), (-30.0, 20.0), (10.0, -15.0)):
        cam, true_up = _wall_points(pitch, yaw)
        up = find_wall(cam)
        assert up is not None and angle_deg(up, true_up) < 1.0
        assert angle_deg(LEVEL_UP, true_up) > 9.0  # the level prior alone is off


def test_no_wall_from_a_small_plane_or_a_steep_floor():
    cam, _ = _wall_points(-20.0, width=0.5)  # a torso-sized plane: not a wall
    assert find_wall(cam) is None
    cam, _ = _wall_points(-60.0)  # beyond max_tilt_deg: a floor could look like that
    assert find_wall(cam) is None


def _scene_frame(k: int, performer_z: float) -> DepthFrame:
    """A still, person-sized figure near the camera and the performer farther back, both capsule
    bodies, at 30 fps (frame k)."""
    figure = capsule_body(default_rest_joints(1.9).astype(np.float64) + [-1.2, 0.0, 0.9])
    performer = capsule_body(JOINTS + [1.0, 0.0, performer_z])
    verts = np.concatenate([figure[0], performer[0]])
    faces = np.concatenate([figure[1], performer[1] + len(figure[0])])
    c2w = look_at_camera(3.0, 1.3, 0.4)
    cam = VirtualDepthCamera("oak-d", c2w, noise=NoiseModel(), seed=k)
    return DepthFrame(t_ns=1_000_000_000 + k * 33_333_333, sensor="cam", camera_to_world=c2w,
                      depth_mm=cam.render(verts, faces, room=Room(width=9.0, depth=9.0)), intrinsics=cam.intrinsics)


def _picks(start_z: float, speed: float, config: PreprocessConfig = PreprocessConfig()) -> list[float]:
    """The x of the person found in 24 frames of ``_scene_frame``: the performer still for a
    moment at start_z, then walking at ``speed`` m/s along z (+: toward the camera)."""
    finder = PersonFinder(config)
    picks = []
    for k in range(24):
        cloud = finder.find(_scene_frame(k, start_z + speed * max(k - 4, 0) / 30.0))
        assert cloud is not None
        picks.append(cloud.to_world[0, 3])
    return picks


def test_a_first_pick_of_still_clutter_gives_way_to_the_performer_who_moves():
    picks = _picks(-2.0, 0.9)
    assert picks[0] < -0.9  # the bigger, nearer figure while nothing moves
    # The performer once they move (the previous person's pull kept the figure to the end: it
    # held back a moving performer 2 m from it as much as still clutter).
    assert all(x > 0.7 for x in picks[16:])


def test_a_performer_walking_away_moves_too():
    picks = _picks(-1.6, -0.9)  # nothing of them comes nearer
    assert picks[0] < -0.9
    assert all(x > 0.7 for x in picks[16:])
    # Counting only what came nearer, the still figure keeps them.
    assert all(x < -0.9 for x in _picks(-1.6, -0.9, PreprocessConfig(motion_recede_m=None))[16:])


def test_motion_counts_what_came_nearer_not_the_wall_a_performer_uncovers():
    finder = PersonFinder()
    before = np.full((2, 3), 3000, np.uint16)
    before[:, 0] = 2000  # the performer in the first column, the wall at 3 m behind
    after = np.full((2, 3), 3000, np.uint16)
    after[:, 1] = 2000  # they stepped one column over
    moved = finder._moved((after, before), np.arange(6)).reshape(2, 3)
    assert moved[:, 1].all() and not moved[:, 0].any() and not moved[:, 2].any()
    # Stepping back 0.3 m is the same surface moving away; the wall 1 m behind is what they uncovered.
    back = np.full((2, 3), 3000, np.uint16)
    back[0, 0] = 2300  # the other row shows the wall they uncovered
    moved = finder._moved((back, before), np.arange(6)).reshape(2, 3)
    assert moved[0, 0] and not moved[1, 0] and not moved[:, 1:].any()


def test_the_floor_search_reads_enough_pixels_of_a_small_image():
    finder = PersonFinder()

    def stride(w: int, h: int) -> int:
        f = DepthFrame(t_ns=0, sensor="cam", camera_to_world=np.eye(4), depth_mm=np.zeros((h, w), np.uint16),
                       intrinsics=np.eye(3))
        return finder._floor_stride(f, 4)

    assert stride(640, 400) == 4 and stride(640, 480) == 4  # 16,000 and 19,200 pixels on a stride of 4
    assert stride(320, 240) == 2  # 4,800 on a stride of 4: a floor at a grazing angle keeps too few


def test_a_floor_missing_from_the_coarse_points_is_searched_in_the_finer_ones():
    from models.skeleton.ground import GroundEstimator

    rng = np.random.default_rng(3)
    wall, _ = _wall_points(-10.0)
    floor = np.stack([rng.uniform(-2, 2, 3000), np.full(3000, 1.5), rng.uniform(1.0, 4.0, 3000)], axis=1)
    asked = []

    def finer() -> np.ndarray:
        asked.append(True)
        return np.concatenate([wall, floor])

    ground = GroundEstimator()
    ground.update(0, wall[::20], finer)  # too few points of anything on the coarse stride
    assert asked and ground.source == "floor" and abs(ground.camera_to_world(0.0)[1, 3] - 1.5) < 0.05
    asked.clear()
    ground = GroundEstimator()
    ground.update(0, np.concatenate([wall, floor]), finer)
    assert not asked and ground.source == "floor"  # found on the coarse one: the finer is not read


def test_a_performer_joined_to_the_wall_behind_them_is_split_off_it():
    rng = np.random.default_rng(3)
    wall = np.stack([rng.uniform(-2.0, 2.0, 6000), rng.uniform(0.0, 2.5, 6000), rng.normal(-3.0, 0.01, 6000)])
    verts = capsule_body(JOINTS + [0.0, 0.0, -2.6])[0]
    person = verts[verts[:, 2] > -2.6].T  # the half facing the camera
    # Flying pixels between the performer's silhouette and the wall 40 cm behind join the two.
    bridge = np.stack([rng.uniform(-0.25, 0.25, 300), rng.uniform(0.3, 1.6, 300), rng.uniform(-2.95, -2.55, 300)])
    pts = np.concatenate([wall, person, bridge], axis=1).astype(np.float32)
    eye = np.array([0.0, 1.0])
    assert find_person_cluster(pts, eye, 120, PreprocessConfig(wall_tolerance_m=None), None) is None
    got = find_person_cluster(pts, eye, 120, PreprocessConfig(), None)
    assert got is not None
    found = got[0]
    assert not found[:wall.shape[1]].any()  # no point of the wall
    alone = find_person_cluster(person.astype(np.float32), eye, 120, PreprocessConfig(), None)
    assert alone is not None
    assert found[wall.shape[1]:wall.shape[1] + person.shape[1]].mean() >= alone[0].mean() - 0.01


def test_the_face_of_a_box_is_no_wall():
    rng = np.random.default_rng(4)
    face = np.stack([rng.uniform(-0.45, 0.45, 2000), rng.uniform(0.0, 0.8, 2000), rng.normal(-3.0, 0.01, 2000)])
    wall = np.stack([rng.uniform(-2.0, 2.0, 2000), rng.uniform(0.0, 2.5, 2000), rng.normal(-3.0, 0.01, 2000)])
    eye = np.array([0.0, 1.0])
    assert not wall_inliers(face.astype(np.float32), eye, 0.05, 1.8).any()  # 0.9 m wide: cutting it cut the performer
    assert wall_inliers(wall.astype(np.float32), eye, 0.05, 1.8).mean() > 0.99



def _still_performer_beside_a_figure(shared_bvh):
    """Depth frames of a performer holding still 3 m from the camera, and a still figure (a
    cylinder and a head, 1.9 m) nearer the camera: both pass the finder's person tests and
    nothing moves, so its size picks the figure."""
    from live.body.library import load_body
    from live.motion.rig_mapping import load_motion
    from sim.synth import CameraPlacement, SyntheticScene

    scene = SyntheticScene.build(load_motion(shared_bvh / "mb_08_07.bvh"), load_body("adult_male_average"),
                                 placement=CameraPlacement(3.0, 1.3, 0.0, 0.1), seed=1)
    c2w = scene.camera.camera_to_world
    toward = (c2w[:3, 3] - [0.0, c2w[1, 3], 0.0]) / np.hypot(c2w[0, 3], c2w[2, 3])  # on the floor, to the camera
    side = np.cross([0.0, 1.0, 0.0], toward)
    at = 1.2 * toward - 1.0 * side
    figure = merge_meshes([capsule_mesh(at + [0.0, 0.3, 0.0], at + [0.0, 1.45, 0.0], 0.22),
                           capsule_mesh(at + [0.0, 1.72, 0.0], at + [0.0, 1.76, 0.0], 0.12)])
    body = scene.vertices(40)
    verts = np.concatenate([body, figure[0]])
    faces = np.concatenate([np.asarray(scene.body.faces), figure[1] + len(body)])
    pelvis = scene.joints[40, 0]
    frames = [DepthFrame(t_ns=1_000_000_000 + k * 33_333_333, sensor="cam", camera_to_world=c2w,
                         depth_mm=scene.camera.render(verts, faces, room=scene.room), intrinsics=scene.camera.intrinsics)
              for k in range(4)]
    return frames, pelvis


def test_the_stage_does_not_take_a_still_figure_that_fits_no_skeleton(shared_bvh):
    from models.skeleton.body_fit import body_fit
    from models.skeleton.runtime import SkeletonStage

    frames, pelvis = _still_performer_beside_a_figure(shared_bvh)
    finder = PersonFinder()
    alone = [finder.find(f) for f in frames]
    assert all(np.hypot(*(c.to_world[[0, 2], 3] - pelvis[[0, 2]])) > 1.0 for c in alone)  # the figure
    stage = SkeletonStage(temporal=False)
    for f in frames:
        skeleton = stage.estimate(f)
        assert np.hypot(*(skeleton.joints[0, [0, 2]] - pelvis[[0, 2]])) < 0.2
    assert stage.finder.counters.body_switches >= 1
    # Why: the figure's sample lies far from the bones of the skeleton regressed from it.
    cloud = alone[0]
    assert body_fit(stage.regressor(cloud.points), cloud.points) > 0.14
    assert body_fit(stage.regressor(stage.last_cloud.points), stage.last_cloud.points) < 0.12


def test_body_fit_is_the_mean_distance_to_the_nearest_bone():
    from models.skeleton.body_fit import body_fit, bone_distances

    joints = JOINTS
    on_bones = np.array([(joints[c] + joints[p]) / 2 for p, c in BONES])
    assert np.allclose(bone_distances(joints, on_bones), 0.0, atol=1e-9)
    # 30 cm beyond the head along its bone, and a point on a bone.
    head, neck = joints[JOINT_INDEX["head"]], joints[JOINT_INDEX["neck"]]
    off = np.array([head + 0.3 * (head - neck) / np.linalg.norm(head - neck), on_bones[0]])
    assert np.allclose(bone_distances(joints, off), [0.3, 0.0], atol=1e-9)
    assert body_fit(joints, off, every=1) == pytest.approx(0.15)
    assert body_fit(joints, np.repeat(off, 4, axis=0)) == pytest.approx(0.15)  # every 4th point
