"""live.imu.fusion_visibility: is a bone seen in the depth image where it is said to be."""

import numpy as np

from live.core.depth import intrinsics_matrix
from live.core.frames import DepthFrame
from live.imu.fusion_visibility import seen_fraction

K = intrinsics_matrix(400.0, 400.0, 160.0, 120.0)
W, H = 320, 240


def _image(bar_depth_m: float | None = 3.0, wall_m: float = 5.0, occluder_m: float | None = None) -> np.ndarray:
    """A wall, a horizontal bar (an arm: rows 110-130, columns 100-220) and maybe something in
    front of the bar; camera frame = world frame here (identity camera_to_world)."""
    img = np.full((H, W), int(wall_m * 1000), np.uint16)
    if bar_depth_m is None:
        img[110:131, 100:221] = 0  # no data where the bar is
    else:
        img[110:131, 100:221] = int(bar_depth_m * 1000)
    if occluder_m is not None:
        img[100:141, 90:231] = int(occluder_m * 1000)
    return img


def _bar_bone(z: float = 3.0, dx: float = 0.0, dy: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The bone along the bar's middle row (v = 120), from u = 105 to 215, at depth z."""
    u0, u1 = 105.0, 215.0
    start = np.array([(u0 - 160.0) * z / 400.0 + dx, dy, z])
    end = np.array([(u1 - 160.0) * z / 400.0 + dx, dy, z])
    return start[None], end[None]


def _seen(img: np.ndarray, bone: tuple[np.ndarray, np.ndarray]) -> float:
    frame = DepthFrame(t_ns=0, sensor="cam", depth_mm=img, intrinsics=K)
    return float(seen_fraction(frame, np.eye(4), *bone)[0])


def test_a_bone_on_its_surface_is_seen():
    assert _seen(_image(), _bar_bone()) == 1.0
    assert _seen(_image(), _bar_bone(z=3.03)) == 1.0  # the axis a few cm behind the surface


def test_a_bone_the_camera_does_not_show_is_not_seen():
    assert _seen(_image(bar_depth_m=None), _bar_bone()) == 0.0           # no depth there
    assert _seen(_image(occluder_m=2.0), _bar_bone()) == 0.0              # something in front
    assert _seen(_image(), _bar_bone(dy=0.25)) == 0.0                     # the camera sees the wall past it
    assert _seen(_image(), _bar_bone(z=3.3)) == 0.0                       # behind the bar
    assert _seen(_image(), _bar_bone(z=-3.0)) == 0.0                      # behind the camera


def test_out_of_the_image_is_not_seen_and_partly_out_is_partly_seen():
    assert _seen(_image(), _bar_bone(dx=-3.0)) == 0.0
    img = _image()
    img[:, 160:] = 0  # the right half of the image has no data
    s = _seen(img, _bar_bone())
    assert 0.0 < s < 1.0


def test_several_bones_at_once():
    img = _image()
    s0, e0 = _bar_bone()
    s1, e1 = _bar_bone(dy=0.25)
    frame = DepthFrame(t_ns=0, sensor="cam", depth_mm=img, intrinsics=K)
    out = seen_fraction(frame, np.eye(4), np.concatenate([s0, s1]), np.concatenate([e0, e1]))
    assert out.tolist() == [1.0, 0.0]


# -- the fusion stage with depth images -------------------------------------------------------

def _render(joints: np.ndarray, c2w: np.ndarray, k: np.ndarray, occluded: set[int], size=(120, 160)) -> np.ndarray:
    """A depth image (mm) of the skeleton drawn as tubes around its bones (5 cm, the torso's 12),
    splatted with a z-buffer; bones into ``occluded`` joints hidden by something 1.5 m from the
    camera covering them (their tubes widened to 10 cm, drawn at that distance)."""
    from live.core.skeleton import BONES, JOINT_INDEX

    torso = {JOINT_INDEX[n] for n in ("spine1", "spine2", "spine3", "neck", "left_hip", "right_hip")}
    pts, hidden = [], []
    ring = np.linspace(0.0, 2 * np.pi, 16, endpoint=False)
    for p, c in BONES:
        a, b = joints[p], joints[c]
        axis = (b - a) / max(np.linalg.norm(b - a), 1e-9)
        n1 = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
        n1 /= np.linalg.norm(n1)
        n2 = np.cross(axis, n1)
        radius = 0.12 if c in torso else 0.10 if c in occluded else 0.05
        for s in np.linspace(0.0, 1.0, 24):
            centre = a + s * (b - a)
            pts.append(centre + radius * (np.cos(ring)[:, None] * n1 + np.sin(ring)[:, None] * n2))
            hidden.append(np.full(len(ring), c in occluded))
    cam = (np.concatenate(pts) - c2w[:3, 3]) @ c2w[:3, :3]
    u = np.rint(cam[:, 0] / cam[:, 2] * k[0, 0] + k[0, 2]).astype(int)
    v = np.rint(cam[:, 1] / cam[:, 2] * k[1, 1] + k[1, 2]).astype(int)
    z = np.where(np.concatenate(hidden), 1.5, cam[:, 2])
    h, w = size
    ok = (cam[:, 2] > 0.1) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    zbuf = np.full(h * w, 65535, np.int64)
    np.minimum.at(zbuf, v[ok] * w + u[ok], np.rint(z[ok] * 1000).astype(np.int64))
    zbuf[zbuf == 65535] = 0
    return zbuf.reshape(h, w).astype(np.uint16)


def test_fusion_trusts_the_suit_on_an_arm_the_image_does_not_show(tmp_path, shared_bvh):
    """Something in front of the camera hides the left arm for 2 s while the regressor reports
    the arm 5 cm off with full confidence (close enough to pass for noise against the suit): with
    the depth images the fusion finds no arm where the suit puts it and follows the suit; without
    them it splits the difference."""
    from live.core.frames import FrameResult, SkeletonFrame
    from live.core.skeleton import JOINT_INDEX, default_rest_joints
    from live.imu.stage import build_stages
    from live.motion.clips import resample
    from live.motion.rig_mapping import load_motion
    from live.pipeline.runner import Pipeline
    from sim.imu_stream import MotionScene, NoisySkeletonStage, write_suit_session
    from sim.replay import ReplaySource

    motion = resample(load_motion(shared_bvh / "cc_002_05.bvh"), 30.0)
    scene = MotionScene.of(motion, default_rest_joints(1.68))
    path = tmp_path / "s.mcap"
    write_suit_session(path, scene, seed=3, frames=240)
    from live.io.session import SessionReader

    meta = next(s.meta for s in SessionReader(path).info.streams if s.kind == "serial")
    arm = [JOINT_INDEX["left_elbow"], JOINT_INDEX["left_wrist"]]
    k = intrinsics_matrix(200.0, 200.0, 80.0, 60.0)
    c2w = np.eye(4)
    c2w[:3, :3] = np.diag([1.0, -1.0, -1.0])  # looking along -z, y up in the world
    c2w[:3, 3] = scene.root.mean(axis=0) + np.array([0.0, 0.2, 3.2])

    def lost(t_ns: int) -> bool:
        return 3.0 <= (t_ns - 1_000_000_000) / 1e9 < 5.0

    class Camera(NoisySkeletonStage):
        """Ground truth + noise as the skeleton, and a rendered depth image of the true body."""

        def process(self, result: FrameResult) -> bool:
            ok = super().process(result)
            if not ok or result.truth is None:
                return ok
            truth = np.asarray(result.truth.joints, np.float64)
            img = _render(truth, c2w, k, set(arm) if lost(result.t_ns) else set())
            result.depth = DepthFrame(t_ns=result.t_ns, sensor="cam", camera_to_world=c2w, depth_mm=img, intrinsics=k)
            joints = np.asarray(result.skeleton.joints, np.float64).copy()
            conf = np.asarray(result.skeleton.confidence).copy()
            if lost(result.t_ns):
                joints[arm] += np.array([0.03, -0.03, 0.03])
                conf[arm] = 1.0
            result.skeleton = SkeletonFrame(result.t_ns, joints.astype(np.float32), conf, camera_to_world=c2w)
            return ok

    def run(with_images: bool) -> tuple[float, dict]:
        depth_stage = Camera(occlusion_every_s=0.0, seed=4)
        stages = build_stages("fused", depth_stage=depth_stage, stream_meta=meta, height=1.75)
        if not with_images:
            orig = depth_stage.process

            def no_image(result):
                ok = orig(result)
                result.depth = None
                return ok

            depth_stage.process = no_image
        errs = []

        def keep(r):
            if r.skeleton is not None and r.truth is not None and lost(r.t_ns):
                errs.append(np.linalg.norm(np.asarray(r.skeleton.joints)[arm] - r.truth.joints[arm], axis=-1).mean())

        Pipeline([ReplaySource(path)], stages, mode="every", on_result=keep).run()
        return float(np.mean(errs)), stages[1].fuser.counters

    e_with, counters = run(True)
    e_without, _ = run(False)
    assert counters["unseen_joint_frames"] > 0
    assert e_with < 0.04 and e_with < 0.8 * e_without, (e_with, e_without)  # 35 against 53 mm
