"""Synthetic sessions: ground truth matches the BVH, rendered points lie on the body, same seed
same bytes, and the session replays like a recorded one."""

import numpy as np

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
